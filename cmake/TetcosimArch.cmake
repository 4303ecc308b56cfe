# Instruction set of the build (TETCOSIM_ARCH):
#   auto      x86-64-v3 (AVX2 and FMA: x86-64 CPUs since about 2015) when the
#             compiler targets x86-64 and the build machine runs it; else
#             the compiler's default. The default.
#   portable  the compiler's default (baseline x86-64: SSE2).
#   <name>    -march=<name>, e.g. native.
# The element loops of deformable/ run four elements per SIMD register
# (deformable/corotational.h's Lanes): AVX2 holds all four, SSE2 two. A
# deformable step at 2058 tetrahedra takes about 30% less time with
# x86-64-v3 than with the baseline (bench/deformable_bench). Results are
# bit-identical for the same binary; builds for different instruction sets
# may differ by rounding (fused multiply-adds).
set(TETCOSIM_ARCH "auto" CACHE STRING "Instruction set: auto, portable, or a -march name")
if(TETCOSIM_ARCH STREQUAL "auto")
  include(CheckCXXSourceRuns)
  set(CMAKE_REQUIRED_FLAGS "-march=x86-64-v3")
  check_cxx_source_runs(
    "int main() { return __builtin_cpu_supports(\"avx2\") && __builtin_cpu_supports(\"fma\") ? 0 : 1; }"
    TETCOSIM_RUNS_X86_64_V3)
  unset(CMAKE_REQUIRED_FLAGS)
  if(TETCOSIM_RUNS_X86_64_V3)
    add_compile_options(-march=x86-64-v3)
    message(STATUS "tetcosim: instruction set x86-64-v3 (TETCOSIM_ARCH=auto)")
  else()
    message(STATUS "tetcosim: instruction set: the compiler's default (TETCOSIM_ARCH=auto)")
  endif()
elseif(NOT TETCOSIM_ARCH STREQUAL "portable" AND NOT TETCOSIM_ARCH STREQUAL "")
  add_compile_options(-march=${TETCOSIM_ARCH})
  message(STATUS "tetcosim: instruction set ${TETCOSIM_ARCH}")
endif()
