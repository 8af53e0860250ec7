// Counts heap allocations made by this test binary (global operator new is replaced in
// allocation_counter.cpp), so tests can show that real-time paths never allocate. One copy, linked as an
// object library (an archive member replacing operator new might not be pulled in).
#pragma once

#include <atomic>

namespace tendril::testing {
extern std::atomic<long> allocation_count;
}  // namespace tendril::testing
