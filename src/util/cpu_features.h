// What this CPU can run. The project's own vector kernels (SIFT, the filters, the warps, ECC,
// corners, the store's halving) take AVX-512 where the CPU has it and OpenCV's call or a scalar
// twin elsewhere; each asks here, once, instead of asking the CPU itself.
#pragma once

namespace rolamos {

// AVX-512 (foundation), with the AVX2 and FMA every such CPU also has.
inline bool CpuHasAvx512() {
  static const bool has =
      __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
  return has;
}

// AVX-512 with its byte and word instructions on 128- to 512-bit vectors (the perspective warp).
inline bool CpuHasAvx512Bw() {
  static const bool has = CpuHasAvx512() && __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512vl");
  return has;
}

// AVX-512BW with byte permutes across a whole vector (VBMI) and BMI2's bit deposit and extract:
// grey from BGR, the masked tiles' split.
inline bool CpuHasAvx512Vbmi() {
  static const bool has =
      CpuHasAvx512Bw() && __builtin_cpu_supports("avx512vbmi") && __builtin_cpu_supports("bmi2");
  return has;
}

// AVX-512BW with the 16-bit dot products of VNNI (SIFT's descriptor distances).
inline bool CpuHasAvx512Vnni() {
  static const bool has = CpuHasAvx512Bw() && __builtin_cpu_supports("avx512vnni");
  return has;
}

// AVX2 (the Lucas-Kanade rows, the canvas's colour rows), and AVX2 with FMA (the warps).
inline bool CpuHasAvx2() {
  static const bool has = __builtin_cpu_supports("avx2");
  return has;
}
inline bool CpuHasAvx2Fma() {
  static const bool has = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
  return has;
}

}  // namespace rolamos
