#include "allocation_counter.hpp"

#include <cstddef>
#include <cstdlib>
#include <new>

namespace tendril::testing {
std::atomic<long> allocation_count{0};

void allocate_probe() { ::operator delete(::operator new(sizeof(double))); }
}  // namespace tendril::testing

// Defined out of line so callers cannot inline them (keeps GCC's new/delete pairing check quiet).
void* operator new(std::size_t size) {
  tendril::testing::allocation_count.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
