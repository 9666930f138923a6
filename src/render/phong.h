/// \file phong.h
/// The Blinn-Phong power nh^e of the Whitted integrator's specular lobe (internal; tested in
/// tests/fresnel_test.cpp).
#pragma once

#include <cmath>
#include <cstdint>

namespace specula {

/// Whole exponents up to this are raised by squaring (every built-in material's is: 16 to 400).
inline constexpr uint32_t kMaxSquaringExponent = 4096;

/// \p e when it is a whole number in [1, kMaxSquaringExponent], else 0 (powf then).
inline uint32_t whole_exponent(float e) {
  if (!(e >= 1.0f) || !(e <= static_cast<float>(kMaxSquaringExponent)) || std::floor(e) != e) return 0;
  return static_cast<uint32_t>(e);
}

/// x^e for 0 <= x <= 1, with \p n = whole_exponent(e). A whole exponent is raised by squaring
/// in double: at most 2 log2(n) products, each rounded to 2^-53 relative, leave the double
/// within ~n 2^-52 (< 1e-12 relative for n <= 4096) of the exact power, so its one rounding to
/// float gives the correctly rounded power except that close to a halfway point (powf is
/// correctly rounded in nearly all cases too: the two agree bit for bit on the pool's images).
/// The multiplications' chain is shorter than powf's, and the call is gone: the power was 9-11%
/// of a pool frame's instructions (one per light per specular hit). Other exponents: powf.
inline float phong_power(float x, float e, uint32_t n) {
  if (n == 0) return std::pow(x, e);
  double b = x;
  double r = (n & 1u) ? b : 1.0;
  for (n >>= 1; n != 0; n >>= 1) {
    b *= b;
    if (n & 1u) r *= b;
  }
  return static_cast<float>(r);
}

}  // namespace specula
