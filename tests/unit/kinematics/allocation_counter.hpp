// Counts heap allocations made by this test binary (global operator new is replaced in
// allocation_counter.cpp), so tests can show that the kinematics evaluation never allocates.
#pragma once

#include <atomic>

namespace tendril::kinematics_testing {
extern std::atomic<long> allocation_count;
}  // namespace tendril::kinematics_testing
