/// \file lanes.h
/// Blocks of kBlock items evaluated side by side (internal to src/render): the blocked
/// structure-of-arrays layout the Whitted integrator keeps its per-hit rows in (block_offset(),
/// for_each_block()) and the lane helpers its block passes share: the lights (lighting.h), the
/// mirror and refraction directions (bounce.h) and the gradient sky (sky.h).
///
/// The helpers are GCC vector extensions. Lane by lane each does what its scalar form does,
/// with the same bits: no contraction into FMA (-ffp-contract=off), square root and division
/// correctly rounded in SIMD as in scalar code, selects that pick as the scalar comparisons do.
#pragma once

#include <cfloat>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>

namespace specula::render {

/// Items per block of the SIMD passes: eight floats fill an AVX2 register, the Phong
/// power's doubles an AVX-512 one. (Sixteen, AVX-512 floats, made the water view's frame 28%
/// slower on one pinned thread of the Zen 5 machine: 74.7 against 58.5 ms.)
inline constexpr size_t kBlock = 8;

/// Offset of row \p r of item \p i in a structure of arrays stored block by block: kBlock
/// items, all kRows rows of a block together. A block's row is still one vector, and an item's
/// rows sit at constant offsets from its first, so writing them takes no multiplication by a row
/// length per row (which cost ~48 instructions per lit point when the rows were whole arrays).
template <int kRows>
constexpr size_t block_offset(int r, size_t i) {
  return (i / kBlock) * (kRows * kBlock) + static_cast<size_t>(r) * kBlock + i % kBlock;
}

/// Runs \p f(block) on each block of the first \p n items of a blocked array (\p data, row r of
/// item i at block_offset<kRows>(r, i); \p block points at a block's row 0). Rows [0, inputs)
/// of the last block's unused items are zeroed first, so \p f reads harmless numbers there
/// (its results for them are never read).
template <int kRows, class F>
void for_each_block(float* data, size_t n, int inputs, F&& f) {
  for (size_t i = n; i % kBlock != 0; ++i)
    for (int r = 0; r < inputs; ++r) data[block_offset<kRows>(r, i)] = 0.0f;
  for (size_t j = 0; j < n; j += kBlock) f(data + block_offset<kRows>(0, j));
}

// The helpers below pass 32- and 64-byte vectors by value. They are always inlined (into
// render_tile, compiled for x86-64, x86-64-v3 and x86-64-v4), so GCC's -Wpsabi note about that
// ABI is off for our targets (CMakeLists.txt).
namespace lanes {

using Fv = float __attribute__((vector_size(4 * kBlock)));
using Iv = int32_t __attribute__((vector_size(4 * kBlock)));

#define SPECULA_LANES_INLINE inline __attribute__((always_inline))

SPECULA_LANES_INLINE Fv load(const float* p) {
  Fv v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
SPECULA_LANES_INLINE Iv load(const int32_t* p) {
  Iv v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
SPECULA_LANES_INLINE Fv splat(float x) {
  Fv v;
  for (size_t i = 0; i < kBlock; ++i) v[i] = x;
  return v;
}
template <class To, class From>
SPECULA_LANES_INLINE To bits(const From& f) {
  static_assert(sizeof(To) == sizeof(From));
  To t;
  std::memcpy(&t, &f, sizeof t);
  return t;
}
/// Lane by lane m ? a : b, for masks of all ones or all zeros (comparison results).
SPECULA_LANES_INLINE Fv select(Iv m, Fv a, Fv b) { return bits<Fv>((m & bits<Iv>(a)) | (~m & bits<Iv>(b))); }

/// Correctly rounded square roots (the scalar std::sqrt's bits). whitted.cpp is compiled with
/// -fno-math-errno, which lets GCC make this one vector instruction per register.
SPECULA_LANES_INLINE Fv sqrt_lanes(Fv x) {
  Fv r;
  for (size_t i = 0; i < kBlock; ++i) r[i] = std::sqrt(x[i]);
  return r;
}

/// std::clamp(v, lo, hi) lane by lane: v < lo ? lo : (hi < v ? hi : v).
SPECULA_LANES_INLINE Fv clamp_lanes(Fv v, Fv lo, Fv hi) { return select(v < lo, lo, select(hi < v, hi, v)); }

/// normalize() lane by lane: (x, y, z) times 1 / length, or zero unless the length is finite
/// and positive.
SPECULA_LANES_INLINE void normalize_lanes(Fv& x, Fv& y, Fv& z) {
  const Fv zero{}, one = splat(1.0f);
  const Fv len = sqrt_lanes(x * x + y * y + z * z);
  const Iv unit = (len > zero) & (len <= splat(FLT_MAX));
  const Fv inv = one / len;
  x = select(unit, x * inv, zero), y = select(unit, y * inv, zero), z = select(unit, z * inv, zero);
}

/// Half a block's lanes in double: four doubles fill an AVX2 register. lit_detail::power_lanes()
/// works on two such halves rather than one eight-double vector, which AVX2 has no register for:
/// GCC lowered that one's 64-bit compares and selects lane by lane through the stack, which cost
/// the x86-64-v3 clone of render_tile 87.8 against 68.0 ms for the water view on an Intel Xeon
/// (AVX-512 machines run the x86-64-v4 clone, which had no such trouble).
using Dh = double __attribute__((vector_size(4 * kBlock)));
using Lh = int64_t __attribute__((vector_size(4 * kBlock)));
SPECULA_LANES_INLINE Dh select(Lh m, Dh a, Dh b) { return bits<Dh>((m & bits<Lh>(a)) | (~m & bits<Lh>(b))); }

}  // namespace lanes

}  // namespace specula::render
