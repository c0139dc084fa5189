#pragma once
// Runtime dispatch for the hot loops (lens-shift fitter, unwrapper, frame gathering): a function
// marked MESOSCAN_SIMD_CLONES gets an AVX2 clone (4 double lanes in one register) and the baseline
// x86-64 one (two SSE2 halves), chosen once by the loader; the binary still runs on any x86-64.
// No FMA in either clone, so both round every operation the same way: the results do not depend
// on the machine. GCC on Linux only (not under ASan, whose interceptors and ifuncs do not mix);
// elsewhere the attribute is empty.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && \
    !defined(__SANITIZE_ADDRESS__) && defined(__linux__)
#define MESOSCAN_SIMD_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define MESOSCAN_SIMD_CLONES
#endif
