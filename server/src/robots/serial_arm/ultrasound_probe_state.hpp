// The ultrasound probe's state as the us_arm's sweep controller publishes it and the imaging worker
// (ultrasound_topics.hpp) reads it: the meeting point of the sweep (control thread) and the
// reconstruction (its own worker thread), so that neither waits for the other.
//
// Frames and units: poses in the world frame, mm; time in s (the controller's clock); force in N.
// world_T_limb is the limb's (tissue frame's) pose as the sweep's motion compensation uses it.
#pragma once

#include <Eigen/Geometry>
#include <cstdint>
#include <optional>

#include "tendril/drivers/hardware/latest_value.hpp"

namespace tendril::server {

struct UltrasoundProbeState {
  double t = 0.0;
  Eigen::Isometry3d world_T_probe = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d world_T_limb = Eigen::Isometry3d::Identity();
  double normal_force_n = 0.0;
  bool in_contact = false;
  bool acquiring = false;  // the acquisition gate is open at via_point
  int via_point = -1;      // −1: no via-point (not sweeping)
};

// The newest probe state: written by one thread (the control thread: never waits, never allocates),
// read by any. Eigen's matrices are not trivially copyable, so the slot keeps a plain copy in a
// hardware::LatestValue seqlock.
class UltrasoundProbeStateSlot {
 public:
  void publish(const UltrasoundProbeState& s) noexcept {
    Packed p;
    p.t = s.t;
    for (int i = 0; i < 16; ++i) {
      p.probe[i] = s.world_T_probe.matrix().data()[i];
      p.limb[i] = s.world_T_limb.matrix().data()[i];
    }
    p.normal_force_n = s.normal_force_n;
    p.in_contact = s.in_contact;
    p.acquiring = s.acquiring;
    p.via_point = s.via_point;
    p.present = true;
    slot_.store(p);
  }

  // Nothing before the first publish().
  std::optional<UltrasoundProbeState> latest() const noexcept {
    const Packed p = slot_.load();
    if (!p.present) return std::nullopt;
    UltrasoundProbeState s;
    s.t = p.t;
    for (int i = 0; i < 16; ++i) {
      s.world_T_probe.matrix().data()[i] = p.probe[i];
      s.world_T_limb.matrix().data()[i] = p.limb[i];
    }
    s.normal_force_n = p.normal_force_n;
    s.in_contact = p.in_contact;
    s.acquiring = p.acquiring;
    s.via_point = p.via_point;
    return s;
  }

  // Grows with every publish(): a reader can tell a new state from the one it has.
  std::uint64_t version() const noexcept { return slot_.version(); }

 private:
  struct Packed {
    double t = 0.0;
    double probe[16] = {};  // column-major 4 × 4, as Eigen stores it
    double limb[16] = {};
    double normal_force_n = 0.0;
    bool in_contact = false;
    bool acquiring = false;
    bool present = false;
    int via_point = -1;
  };
  hardware::LatestValue<Packed> slot_;
};

}  // namespace tendril::server
