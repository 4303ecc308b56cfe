#pragma once

// Heap allocations of a test binary that links allocation_counter.cc, on
// every thread. Outside the sanitizers every malloc, calloc, realloc,
// posix_memalign, aligned_alloc and memalign is counted: Eigen's arrays,
// operator new's (libstdc++'s calls malloc) and the OpenMP runtime's
// alike. Under AddressSanitizer, whose runtime owns malloc, every form of
// operator new is counted instead (std::vector and the like, not Eigen's
// arrays).

namespace tetcosim::testing {

long HeapAllocations();   // so far (operator new only: CountsMalloc() false)
long OperatorNewCalls();  // so far, every form
bool CountsMalloc();

}  // namespace tetcosim::testing
