// std::exp of many floats, four at a time where the bits allow it (owner: render). See
// render/exp_lanes.h for why the SIMD path gives std::exp's bits.
#include "render/exp_lanes.h"

#include <bit>
#include <cmath>
#include <cstdint>

#if defined(__x86_64__) && defined(__GNUC__) && defined(__GLIBC__)
#include <immintrin.h>
#define SPECULA_EXP_LANES 1
#else
#define SPECULA_EXP_LANES 0
#endif

namespace specula::render {

namespace {

#if SPECULA_EXP_LANES
// The numbers of glibc's single-precision exp (its data table, read from the library this
// was written against, and checked against std::exp by lighting_test): x e = 2^(x N / ln 2) with
// N = 32 table entries; k = round(x N / ln 2) by adding and subtracting 1.5 * 2^52; then
// 2^(k / N) = table[k mod N] + (k << 47) as 64-bit integers (each entry is the bits of
// 2^(i / N) rounded to double, less i << 47) and 2^(r / N) ~ c0 r^3 + c1 r^2 + c2 r + 1.
constexpr uint64_t kTable[32] = {
    0x3ff0000000000000, 0x3fefd9b0d3158574, 0x3fefb5586cf9890f, 0x3fef9301d0125b51, 0x3fef72b83c7d517b,
    0x3fef54873168b9aa, 0x3fef387a6e756238, 0x3fef1e9df51fdee1, 0x3fef06fe0a31b715, 0x3feef1a7373aa9cb,
    0x3feedea64c123422, 0x3feece086061892d, 0x3feebfdad5362a27, 0x3feeb42b569d4f82, 0x3feeab07dd485429,
    0x3feea47eb03a5585, 0x3feea09e667f3bcd, 0x3fee9f75e8ec5f74, 0x3feea11473eb0187, 0x3feea589994cce13,
    0x3feeace5422aa0db, 0x3feeb737b0cdc5e5, 0x3feec49182a3f090, 0x3feed503b23e255d, 0x3feee89f995ad3ad,
    0x3feeff76f2fb5e47, 0x3fef199bdd85529c, 0x3fef3720dcef9069, 0x3fef5818dcfba487, 0x3fef7c97337b9b5f,
    0x3fefa4afa2a490da, 0x3fefd0765b6e4540};
constexpr double kInvLn2N = std::bit_cast<double>(uint64_t{0x40471547652b82fe});  // 32 / ln 2
constexpr double kShift = std::bit_cast<double>(uint64_t{0x4338000000000000});    // 1.5 * 2^52
constexpr double kC0 = std::bit_cast<double>(uint64_t{0x3ebc6af84b912394});
constexpr double kC1 = std::bit_cast<double>(uint64_t{0x3f2ebfce50fac4f3});
constexpr double kC2 = std::bit_cast<double>(uint64_t{0x3f962e42ff0c52d6});
static_assert(std::bit_cast<double>(kTable[16] + (uint64_t{16} << 47)) == 0x1.6a09e667f3bcdp0,
              "table entry 16 is sqrt(2) less 16 << 47");

/// Biased exponent and top three mantissa bits of |x| (glibc's top12): at or above 0x42a,
/// |x| >= 80 or x is not finite, which glibc handles apart (and so do we, by calling it).
constexpr int kSpecialTop = 0x42a;

__attribute__((target("avx2,fma"))) void exp_fma(float* x, size_t n) {
  const __m256d inv_ln2n = _mm256_set1_pd(kInvLn2N), shift = _mm256_set1_pd(kShift);
  const __m256d c0 = _mm256_set1_pd(kC0), c1 = _mm256_set1_pd(kC1), c2 = _mm256_set1_pd(kC2);
  const __m256d one = _mm256_set1_pd(1.0);
  const __m256i index_mask = _mm256_set1_epi64x(31);
  const auto* table = reinterpret_cast<const long long*>(kTable);
  size_t i = 0;
  for (; i + 4 <= n; i += 4) {
    const __m128 xf = _mm_loadu_ps(x + i);
    const __m128i top = _mm_and_si128(_mm_srli_epi32(_mm_castps_si128(xf), 20), _mm_set1_epi32(0x7ff));
    const int special = _mm_movemask_ps(_mm_castsi128_ps(_mm_cmpgt_epi32(top, _mm_set1_epi32(kSpecialTop - 1))));
    const __m256d xd = _mm256_cvtps_pd(xf);
    // Fused as glibc's FMA build fuses them: k + shift = x N / ln 2 + shift in one rounding,
    // r = x N / ln 2 - k in one rounding.
    const __m256d kd_shifted = _mm256_fmadd_pd(inv_ln2n, xd, shift);
    const __m256i ki = _mm256_castpd_si256(kd_shifted);
    const __m256d kd = _mm256_sub_pd(kd_shifted, shift);
    const __m256d r = _mm256_fmsub_pd(inv_ln2n, xd, kd);
    const __m256i t = _mm256_add_epi64(_mm256_i64gather_epi64(table, _mm256_and_si256(ki, index_mask), 8),
                                       _mm256_slli_epi64(ki, 47));
    const __m256d s = _mm256_castsi256_pd(t);
    const __m256d z = _mm256_fmadd_pd(r, c0, c1);
    const __m256d r2 = _mm256_mul_pd(r, r);
    __m256d y = _mm256_fmadd_pd(r, c2, one);
    y = _mm256_fmadd_pd(z, r2, y);
    y = _mm256_mul_pd(y, s);
    if (special == 0) {
      _mm_storeu_ps(x + i, _mm256_cvtpd_ps(y));
      continue;
    }
    alignas(16) float in[4], out[4];
    _mm_store_ps(in, xf);
    _mm_store_ps(out, _mm256_cvtpd_ps(y));
    for (int l = 0; l < 4; ++l) x[i + static_cast<size_t>(l)] = (special >> l) & 1 ? std::exp(in[l]) : out[l];
  }
  for (; i < n; ++i) x[i] = std::exp(x[i]);
}

bool detect_simd() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
}
#endif

}  // namespace

bool exp_lanes_simd() {
#if SPECULA_EXP_LANES
  static const bool simd = detect_simd();
  return simd;
#else
  return false;
#endif
}

void exp_in_place(float* x, size_t n) {
#if SPECULA_EXP_LANES
  if (exp_lanes_simd()) {
    exp_fma(x, n);
    return;
  }
#endif
  for (size_t i = 0; i < n; ++i) x[i] = std::exp(x[i]);
}

}  // namespace specula::render
