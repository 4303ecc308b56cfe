#include "tests/support/allocation_counter.h"

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstddef>
#include <cstdlib>
#include <new>

namespace {

std::atomic<long> heap_allocations{0};
std::atomic<long> operator_new_calls{0};

#if defined(__SANITIZE_ADDRESS__)
constexpr bool kCountsMalloc = false;
#else
constexpr bool kCountsMalloc = true;
#endif

void CountOperatorNew() {
  operator_new_calls.fetch_add(1, std::memory_order_relaxed);
  if (!kCountsMalloc) heap_allocations.fetch_add(1, std::memory_order_relaxed);
}

}  // namespace

namespace tetcosim::testing {
long HeapAllocations() {
  return heap_allocations.load(std::memory_order_relaxed);
}
long OperatorNewCalls() {
  return operator_new_calls.load(std::memory_order_relaxed);
}
bool CountsMalloc() {
  return kCountsMalloc;
}
}  // namespace tetcosim::testing

void* operator new(std::size_t size) {
  CountOperatorNew();
  if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}
// (not inlined: inlined into a caller, GCC pairs the free with its own
// idea of operator new and warns of a mismatch, -Wmismatched-new-delete)
[[gnu::noinline]] void operator delete(void* p) noexcept {
  std::free(p);
}
[[gnu::noinline]] void operator delete(void* p, std::size_t) noexcept {
  std::free(p);
}
void* operator new(std::size_t size, std::align_val_t alignment) {
  CountOperatorNew();
  // (aligned_alloc takes a whole number of alignments)
  const auto align = static_cast<std::size_t>(alignment);
  if (void* p =
          std::aligned_alloc(align, (std::max<std::size_t>(size, 1) + align - 1) / align * align)) {
    return p;
  }
  throw std::bad_alloc();
}
[[gnu::noinline]] void operator delete(void* p, std::align_val_t) noexcept {
  std::free(p);
}
[[gnu::noinline]] void operator delete(void* p, std::size_t, std::align_val_t) noexcept {
  std::free(p);
}

#if !defined(__SANITIZE_ADDRESS__)

// malloc and its kin, counted, then glibc's own under their internal names:
// the executable's definitions take the place of glibc's for the whole
// process (they come first in symbol lookup), and free stays glibc's
extern "C" {
// NOLINTBEGIN(bugprone-reserved-identifier,readability-identifier-naming): glibc's names
void* __libc_malloc(std::size_t size) noexcept;
void* __libc_calloc(std::size_t count, std::size_t size) noexcept;
void* __libc_realloc(void* p, std::size_t size) noexcept;
void* __libc_memalign(std::size_t alignment, std::size_t size) noexcept;

void* malloc(std::size_t size) noexcept {
  heap_allocations.fetch_add(1, std::memory_order_relaxed);
  return __libc_malloc(size);
}
void* calloc(std::size_t count, std::size_t size) noexcept {
  heap_allocations.fetch_add(1, std::memory_order_relaxed);
  return __libc_calloc(count, size);
}
void* realloc(void* p, std::size_t size) noexcept {
  heap_allocations.fetch_add(1, std::memory_order_relaxed);
  return __libc_realloc(p, size);
}
void* memalign(std::size_t alignment, std::size_t size) noexcept {
  heap_allocations.fetch_add(1, std::memory_order_relaxed);
  return __libc_memalign(alignment, size);
}
void* aligned_alloc(std::size_t alignment, std::size_t size) noexcept {
  heap_allocations.fetch_add(1, std::memory_order_relaxed);
  return __libc_memalign(alignment, size);
}
int posix_memalign(void** p, std::size_t alignment, std::size_t size) noexcept {
  heap_allocations.fetch_add(1, std::memory_order_relaxed);
  if (alignment % sizeof(void*) != 0 || (alignment & (alignment - 1)) != 0) return EINVAL;
  void* block = __libc_memalign(alignment, size);
  if (block == nullptr && size != 0) return ENOMEM;
  *p = block;
  return 0;
}
// NOLINTEND(bugprone-reserved-identifier,readability-identifier-naming)
}  // extern "C"

#endif
