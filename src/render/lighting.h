/// \file lighting.h
/// Direct lighting of the Whitted integrator's hits by one light (internal to src/render;
/// tested in tests/lighting_test.cpp): sample_light() for one surface point, LitPoints for the
/// lit points of a whole wavefront, evaluated light by light in blocks of kBlock points.
///
/// Why blocks: for one point and one light the lighting is a single chain of dependent
/// operations (a square root and a division to normalise the half vector, then up to twelve
/// dependent squarings of the Phong power), so a hit at a time the core waits on latencies
/// (the light loop was a third of a 1920x1200 pool frame). The same operations for a block
/// of points side by side overlap. Lane by lane they are the operations of sample_light() in the
/// same order (no contraction into FMA: -ffp-contract=off; square root and division are
/// correctly rounded in SIMD as in scalar code), so every contribution has the same bits.
#pragma once

#include <cfloat>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

#include "render/lanes.h"
#include "render/phong.h"
#include "specula/math.h"


namespace specula::render {

/// What the lights need of a lit surface point.
struct LitPoint {
  Vec3 p;         ///< the point (on the surface up to rounding)
  Vec3 ng_f;      ///< unit geometric normal facing the incoming ray
  Vec3 ns_f;      ///< unit shading normal on the same side
  Vec3 view_dir;  ///< unit direction of the incoming ray
  Vec3 weight;    ///< path throughput
  Vec3 kd;        ///< diffuse weight of the material (colour * local share)
  Vec3 specular;  ///< specular colour
  float exponent = 0.0f;    ///< Phong exponent
  float zero_below = 0.0f;  ///< spec_zero_below(exponent): the power is +0 below this
  uint32_t phong_int = 0;   ///< whole_exponent(exponent), 0: powf
  bool has_spec = false;    ///< specular colour non-zero
};

/// The contribution \p c of a light from unit direction \p l (towards the light) with
/// \p irradiance (before the cosine) at \p q: Lambert plus Blinn-Phong, times the throughput.
/// False when there is none (light behind the surface, or nothing positive).
inline bool sample_light(const LitPoint& q, const Vec3& l, const Vec3& irradiance, Vec3& c) {
  if (dot(l, q.ng_f) <= 0.0f) return false;  // light behind the surface
  const float cos_l = dot(q.ns_f, l);
  if (cos_l <= 0.0f) return false;
  Vec3 f = q.kd * cos_l;
  if (q.has_spec) {
    const Vec3 h = normalize(l - q.view_dir);
    const float nh = std::max(0.0f, dot(q.ns_f, h));
    if (nh > 0.0f) f += q.specular * (nh < q.zero_below ? 0.0f : phong_power(nh, q.exponent, q.phong_int));
  }
  c = q.weight * f * irradiance;
  return max_component(c) > 0.0f;
}

/// The lit points of one wavefront, structure of arrays in blocks, and per light the contributions
/// evaluate_light() found for them. Storage only grows: reset() for every wavefront.
class LitPoints {
 public:
  /// Empties the set and makes room for \p n points and \p lights lights.
  void reset(size_t n, size_t lights) {
    n_ = 0;
    stride_ = (n + kBlock - 1) / kBlock * kBlock;
    grow(rows_, kRows * stride_);  // stride_ is a whole number of blocks
    grow(power_, stride_);
    grow(spec_, stride_);
    grow(exponent_, stride_);
    grow(c_, 3 * lights * stride_);
    grow(ok_, lights * stride_);
  }

  /// Adds a point; returns its index.
  uint32_t add(const LitPoint& q) {
    const size_t j = n_++;
    const Vec3* v[7] = {&q.p, &q.ng_f, &q.ns_f, &q.view_dir, &q.weight, &q.kd, &q.specular};
    for (int k = 0; k < 7; ++k) {
      cell(3 * k, j) = v[k]->x;
      cell(3 * k + 1, j) = v[k]->y;
      cell(3 * k + 2, j) = v[k]->z;
    }
    cell(kZero, j) = q.zero_below;
    exponent_[j] = q.exponent;
    power_[j] = static_cast<int32_t>(q.phong_int);
    spec_[j] = q.has_spec ? -1 : 0;
    return static_cast<uint32_t>(j);
  }

  size_t size() const { return n_; }

  LitPoint operator[](size_t j) const {
    LitPoint q;
    Vec3* v[7] = {&q.p, &q.ng_f, &q.ns_f, &q.view_dir, &q.weight, &q.kd, &q.specular};
    for (int k = 0; k < 7; ++k) *v[k] = {cell(3 * k, j), cell(3 * k + 1, j), cell(3 * k + 2, j)};
    q.zero_below = cell(kZero, j);
    q.exponent = exponent_[j];
    q.phong_int = static_cast<uint32_t>(power_[j]);
    q.has_spec = spec_[j] != 0;
    return q;
  }

  /// The position and the geometric normal of point \p j (what a shadow ray starts from).
  Vec3 position(size_t j) const { return {cell(0, j), cell(1, j), cell(2, j)}; }
  Vec3 normal(size_t j) const { return {cell(3, j), cell(4, j), cell(5, j)}; }

  /// Whether point \p j goes through sample_light() one by one: a specular lobe whose exponent
  /// is not whole (powf, which has no SIMD form here).
  bool one_by_one(size_t j) const { return spec_[j] != 0 && power_[j] == 0; }

  /// Evaluates light \p light (an index below reset()'s count) at every point: a directional
  /// light from unit direction \p dir, else a point light at \p position; \p power is its
  /// colour times intensity. Afterwards result() holds what sample_light() gives, bit for bit,
  /// for every point but the one_by_one() ones.
  void evaluate_light(size_t light, bool directional, const Vec3& dir, const Vec3& position, const Vec3& power);

  /// The contribution of light \p light at point \p j (evaluate_light() ran): false when none.
  bool result(size_t light, size_t j, Vec3& c) const {
    const size_t at = 3 * light * stride_ + j;
    c = {c_[at], c_[at + stride_], c_[at + 2 * stride_]};
    return ok_[light * stride_ + j] != 0;
  }

 private:
  enum : int { kZero = 21, kRows = 22 };  ///< rows 0-20: the seven vectors, x y z each
  template <class T>
  static void grow(std::vector<T>& v, size_t n) {
    if (v.size() < n) v.resize(n);
  }
  /// The rows are stored block by block (block_offset()).
  static size_t offset(int r, size_t j) { return block_offset<kRows>(r, j); }
  float& cell(int r, size_t j) { return rows_[offset(r, j)]; }
  float cell(int r, size_t j) const { return rows_[offset(r, j)]; }

  size_t n_ = 0, stride_ = 0;
  std::vector<float> rows_;
  std::vector<int32_t> power_, spec_;
  std::vector<float> exponent_;
  std::vector<float> c_;
  std::vector<int32_t> ok_;
};

namespace lit_detail {

/// phong_power() of a block's lanes with whole exponents \p n (>= 1 where used): the same products
/// in double, lane by lane; a lane whose exponent has fewer bits only squares its base further,
/// which its result never uses.
SPECULA_LANES_INLINE lanes::Fv power_lanes(lanes::Fv x, lanes::Iv n32) {
  using namespace lanes;
  static_assert(kBlock == 8, "power_lanes() splits a block into two halves of four lanes");
  int32_t most = 0;
  for (size_t i = 0; i < kBlock; ++i) most = std::max(most, n32[i]);
  Dh b0 = __builtin_convertvector(__builtin_shufflevector(x, x, 0, 1, 2, 3), Dh);
  Dh b1 = __builtin_convertvector(__builtin_shufflevector(x, x, 4, 5, 6, 7), Dh);
  const Lh n0 = __builtin_convertvector(__builtin_shufflevector(n32, n32, 0, 1, 2, 3), Lh);
  const Lh n1 = __builtin_convertvector(__builtin_shufflevector(n32, n32, 4, 5, 6, 7), Lh);
  const Lh none{}, one_bit = none + 1;
  Dh unit;
  for (size_t i = 0; i < kBlock / 2; ++i) unit[i] = 1.0;
  bool uniform = true;  // one exponent in every lane: neighbouring hits on one material
  for (size_t i = 1; i < kBlock; ++i) uniform = uniform && n32[i] == n32[0];
  Dh r0, r1;
  if (uniform) {
    // The same products, with the exponent's bits tested once for the block instead of a
    // compare and a select per lane and bit (~1% of a pool water frame).
    r0 = (most & 1) ? b0 : unit;
    r1 = (most & 1) ? b1 : unit;
    for (int k = 1; (most >> k) != 0; ++k) {
      b0 = b0 * b0;
      b1 = b1 * b1;
      if ((most >> k) & 1) r0 = r0 * b0, r1 = r1 * b1;
    }
  } else {
    r0 = select((n0 & one_bit) != none, b0, unit);
    r1 = select((n1 & one_bit) != none, b1, unit);
    for (int k = 1; (most >> k) != 0; ++k) {
      b0 = b0 * b0;
      b1 = b1 * b1;
      r0 = select(((n0 >> k) & one_bit) != none, r0 * b0, r0);
      r1 = select(((n1 >> k) & one_bit) != none, r1 * b1, r1);
    }
  }
  using Fh = float __attribute__((vector_size(2 * kBlock)));
  const Fh f0 = __builtin_convertvector(r0, Fh), f1 = __builtin_convertvector(r1, Fh);
  return __builtin_shufflevector(f0, f1, 0, 1, 2, 3, 4, 5, 6, 7);
}

}  // namespace lit_detail

inline void LitPoints::evaluate_light(size_t light, bool directional, const Vec3& dir, const Vec3& position,
                                      const Vec3& power) {
  using namespace lanes;
  using lit_detail::power_lanes;
  const Fv zero = splat(0.0f), one = splat(1.0f);
  float* const cx = c_.data() + 3 * light * stride_;
  float* const cy = cx + stride_;
  float* const cz = cy + stride_;
  int32_t* const ok = ok_.data() + light * stride_;
  for (size_t j = 0; j < n_; j += kBlock) {
    const auto at = [&](int r) { return load(rows_.data() + offset(r, j)); };
    const Fv px = at(0), py = at(1), pz = at(2);
    // The light's direction and irradiance at the points (sample_light's l and irradiance).
    Fv lx, ly, lz, ix, iy, iz;
    Iv valid = Iv{} == Iv{};  // every lane
    if (directional) {
      lx = splat(dir.x), ly = splat(dir.y), lz = splat(dir.z);
      ix = splat(power.x), iy = splat(power.y), iz = splat(power.z);
    } else {
      const Fv tx = splat(position.x) - px, ty = splat(position.y) - py, tz = splat(position.z) - pz;
      const Fv d2 = tx * tx + ty * ty + tz * tz;
      valid = d2 > zero;
      const Fv inv = one / sqrt_lanes(d2);
      lx = tx * inv, ly = ty * inv, lz = tz * inv;
      const Fv inv_d2 = one / d2;
      ix = splat(power.x) * inv_d2, iy = splat(power.y) * inv_d2, iz = splat(power.z) * inv_d2;
    }
    // sample_light().
    const Fv gx = at(3), gy = at(4), gz = at(5), sx = at(6), sy = at(7), sz = at(8);
    const Fv front = lx * gx + ly * gy + lz * gz;
    const Fv cos_l = sx * lx + sy * ly + sz * lz;
    Fv fx = at(15) * cos_l, fy = at(16) * cos_l, fz = at(17) * cos_l;
    Fv hx = lx - at(9), hy = ly - at(10), hz = lz - at(11);
    normalize_lanes(hx, hy, hz);
    const Fv dn = sx * hx + sy * hy + sz * hz;
    const Fv nh = select(zero < dn, dn, zero);  // std::max(0.0f, dn)
    const Fv pw = select(nh < at(kZero), zero, power_lanes(nh, load(power_.data() + j)));
    const Iv spec = load(spec_.data() + j) & (nh > zero);
    fx = select(spec, fx + at(18) * pw, fx);
    fy = select(spec, fy + at(19) * pw, fy);
    fz = select(spec, fz + at(20) * pw, fz);
    const Fv rx = at(12) * fx * ix, ry = at(13) * fy * iy, rz = at(14) * fz * iz;
    const Fv inner = select(ry < rz, rz, ry);  // max_component(): std::max(x, std::max(y, z))
    const Fv most = select(rx < inner, inner, rx);
    const Iv lit = valid & ~(front <= zero) & ~(cos_l <= zero) & (most > zero);
    std::memcpy(cx + j, &rx, sizeof rx);
    std::memcpy(cy + j, &ry, sizeof ry);
    std::memcpy(cz + j, &rz, sizeof rz);
    std::memcpy(ok + j, &lit, sizeof lit);
  }
}

}  // namespace specula::render
