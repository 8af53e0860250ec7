// Counts heap allocations made by this test binary (global operator new is replaced in
// allocation_counter.cpp), so tests can show that real-time paths never allocate. One copy, linked as an
// object library (an archive member replacing operator new might not be pulled in).
#pragma once

#include <atomic>

namespace tendril::testing {
extern std::atomic<long> allocation_count;
// Allocates and frees once through the replaced operator new, so a test can show that the counter sees
// allocations. A plain `std::make_unique<double>()` whose result is unused may be elided by the
// optimizer (clang does at -O2, [expr.new]/14), and the check would then fail for the wrong reason;
// direct calls of ::operator new are never elided.
void allocate_probe();
}  // namespace tendril::testing
