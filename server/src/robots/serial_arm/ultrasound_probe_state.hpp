// UltrasoundProbeState: what the ultrasound arm's control thread tells the imaging side (the SIMULATED
// B-mode probe, the slice mapping of eq. 5, the reconstruction topics) about the probe and the limb,
// once per control tick. Read it off the control thread with SerialArm::probe_state(): a latest-value
// read through a seqlock (hardware::LatestValue), so the control thread never waits for a reader.
//
// Frames: "world" is the arm's base frame {B} (us_arm_base): tendril places no arm elsewhere, so
// world_T_base is the identity and the /tf chain world→us_arm_base is one. The limb frame {P} (the
// tissue-stabilised frame "tissue") moves with the SIMULATED limb; the probe frame {U} is the arm's
// tool frame, z along the probe axis into the tissue. Units: mm, rad, N, s.
#pragma once

#include <array>
#include <cstdint>

#include <Eigen/Geometry>

namespace tendril::server {

struct UltrasoundProbeState {
  std::uint64_t tick = 0;  // control tick of the sample (grows; 0: nothing published yet)
  double t = 0.0;          // control time (s)
  // The probe (tool) pose from the measured joints.
  Eigen::Isometry3d world_T_probe = Eigen::Isometry3d::Identity();
  // The limb as the motion compensation sees it (the SIMULATED 120 Hz tracker: sample-and-hold plus
  // its latency) — the frame to map slices into for a motion-stabilised reconstruction (eq. 5's H_P^G).
  Eigen::Isometry3d world_T_limb = Eigen::Isometry3d::Identity();
  // The limb's true pose now (SIMULATED ground truth, for the simulated B-mode image only).
  Eigen::Isometry3d world_T_limb_true = Eigen::Isometry3d::Identity();
  double normal_force_n = 0.0;  // F_n along the probe axis (positive pressing), from the force sensor
  bool in_contact = false;      // the force phase of the hybrid controller (or F_n over 0.1 N)
  bool acquiring = false;       // the acquisition gate is open: an image taken now is a slice
  int via_point = -1;           // index of the current via-point, -1 without a running sweep
};

// The trivially copyable form the control thread stores (LatestValue holds trivially copyable data
// only; Eigen's transforms are not). Poses as 4×4 column-major matrices.
struct UltrasoundProbeSample {
  std::uint64_t tick = 0;
  double t = 0.0;
  std::array<double, 16> world_T_probe{};
  std::array<double, 16> world_T_limb{};
  std::array<double, 16> world_T_limb_true{};
  double normal_force_n = 0.0;
  bool in_contact = false;
  bool acquiring = false;
  int via_point = -1;
};

inline std::array<double, 16> to_array(const Eigen::Isometry3d& pose) noexcept {
  std::array<double, 16> out{};
  Eigen::Map<Eigen::Matrix4d>(out.data()) = pose.matrix();
  return out;
}

inline Eigen::Isometry3d to_isometry(const std::array<double, 16>& m) noexcept {
  Eigen::Isometry3d pose;
  pose.matrix() = Eigen::Map<const Eigen::Matrix4d>(m.data());
  return pose;
}

inline UltrasoundProbeState to_state(const UltrasoundProbeSample& s) noexcept {
  UltrasoundProbeState out;
  out.tick = s.tick;
  out.t = s.t;
  out.world_T_probe = to_isometry(s.world_T_probe);
  out.world_T_limb = to_isometry(s.world_T_limb);
  out.world_T_limb_true = to_isometry(s.world_T_limb_true);
  out.normal_force_n = s.normal_force_n;
  out.in_contact = s.in_contact;
  out.acquiring = s.acquiring;
  out.via_point = s.via_point;
  return out;
}

}  // namespace tendril::server
