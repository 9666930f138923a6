/// \file bounce.h
/// The mirror and dielectric directions of the Whitted integrator's hits, and where their rays
/// start, a block of kBlock hits at a time (internal to src/render; tested in
/// tests/lighting_test.cpp).
///
/// Per hit these are chains of dependent operations (a dot product, the Fresnel equations with
/// a square root and two divisions, Snell's law with another square root, two normalisations),
/// which the shading loop waited on hit by hit. The integrator records its mirror and dielectric
/// hits (BounceRow rows, structure of arrays), evaluates them here side by side, then makes their
/// rays in shading order. Lane by lane the operations are those of bounce_reference() in the same
/// order (no contraction into FMA: -ffp-contract=off; square root and division are correctly
/// rounded in SIMD as in scalar code; every comparison and clamp selects as its scalar form
/// does, NaN included), so every direction has the same bits.
#pragma once

#include <cstddef>
#include <cstring>

#include "render/fresnel.h"
#include "render/lanes.h"
#include "specula/math.h"
#include "specula/ray.h"

namespace specula::render {

/// Rows of a block of recorded hits: inputs (incoming direction d, shading normal n and
/// geometric normal g, both facing the incoming ray, the relative index of refraction eta and
/// the hit point p), then the outputs of bounce_block().
enum BounceRow : int {
  kBounceDx, kBounceDy, kBounceDz,
  kBounceNx, kBounceNy, kBounceNz,
  kBounceGx, kBounceGy, kBounceGz,
  kBounceEta,
  kBouncePx, kBouncePy, kBouncePz,
  kBounceInputs,                  ///< rows above: written by the integrator
  kBounceFr = kBounceInputs,      ///< Fresnel reflectance through n
  kBounceOk,                      ///< refraction through n kept (int32 all ones) or not (0)
  kBounceTx, kBounceTy, kBounceTz,  ///< the refracted direction (where kBounceOk)
  kBounceMx, kBounceMy, kBounceMz,  ///< the unit mirror direction
  kBounceAx, kBounceAy, kBounceAz,  ///< offset_ray_origin(p, g): where the mirror ray starts
  kBounceBx, kBounceBy, kBounceBz,  ///< offset_ray_origin(p, -g): where the refracted ray starts
  kBounceRows,
};

/// What bounce_block() computes for one hit, in scalar code (the definition it is tested
/// against): \p fr the reflectance, \p ok whether the refraction through the shading normal is
/// kept (it exists and leaves below the geometric surface) with direction \p t, \p mirror the
/// mirror direction (about the shading normal, or the geometric one if that would dip below the
/// geometric surface), normalised; \p above and \p below the origins of the rays that leave p on
/// either side of the geometric surface.
inline void bounce_reference(const Vec3& d, const Vec3& n, const Vec3& g, float eta, const Vec3& p, float& fr,
                             bool& ok, Vec3& t, Vec3& mirror, Vec3& above, Vec3& below) {
  fr = detail::fresnel_dielectric(-dot(d, n), eta);
  ok = fr < 1.0f && detail::refract(d, n, eta, t) && dot(t, g) < 0.0f;
  Vec3 r = reflect(d, n);
  if (dot(r, g) <= 0.0f) r = reflect(d, g);
  mirror = normalize(r);
  above = offset_ray_origin(p, g);
  below = offset_ray_origin(p, -g);
}

/// offset_ray_origin() of one coordinate, lane by lane: \p p moved by trunc(256 n) ulps away
/// from zero, or by n / 65536 where |p| < 1/32 (the same truncation, integer addition, with
/// wrap-around, and ordered compares).
SPECULA_LANES_INLINE lanes::Fv offset_lanes(lanes::Fv p, lanes::Fv n) {
  using namespace lanes;
  using Uv = uint32_t __attribute__((vector_size(4 * kBlock)));
  const Iv of = __builtin_convertvector(splat(256.0f) * n, Iv);
  const Iv neg = p < splat(0.0f);
  const Iv step = (of ^ neg) - neg;  // p < 0 ? -of : of
  const Fv moved = bits<Fv>(bits<Uv>(p) + bits<Uv>(step));
  const Fv abs_p = bits<Fv>(bits<Iv>(p) & (Iv{} + 0x7FFFFFFF));
  return select(abs_p < splat(1.0f / 32.0f), p + splat(1.0f / 65536.0f) * n, moved);
}

/// bounce_reference() for one block of kBlock hits, stored block by block (row r of hit i at
/// block_offset<kBounceRows>(r, i); \p block points at the block's row 0): reads the input
/// rows, writes the output rows.
inline void bounce_block(float* block) {
  using namespace lanes;
  const auto in = [&](int r) { return load(block + static_cast<size_t>(r) * kBlock); };
  const auto out = [&](int r, const auto& v) { std::memcpy(block + static_cast<size_t>(r) * kBlock, &v, sizeof v); };
  const Fv zero = splat(0.0f), one = splat(1.0f), minus_one = splat(-1.0f);
  const Fv dx = in(kBounceDx), dy = in(kBounceDy), dz = in(kBounceDz);
  const Fv nx = in(kBounceNx), ny = in(kBounceNy), nz = in(kBounceNz);
  const Fv gx = in(kBounceGx), gy = in(kBounceGy), gz = in(kBounceGz);
  const Fv eta = in(kBounceEta);
  // std::max(0, v) = 0 < v ? v : 0.
  const auto max0 = [&](Fv v) { return select(zero < v, v, zero); };
  const Fv dn = dx * nx + dy * ny + dz * nz;
  const Fv eta2 = eta * eta;

  // detail::fresnel_dielectric(-dn, eta).
  const Fv ci = clamp_lanes(-dn, zero, one);
  const Fv sin2_t = eta2 * max0(one - ci * ci);
  const Fv cos_t = sqrt_lanes(max0(one - sin2_t));
  const Fv eci = eta * ci, ect = eta * cos_t;
  const Fv ds = eci + cos_t, dp = ci + ect;
  const Fv rs = (eci - cos_t) / ds, rp = (ci - ect) / dp;
  Fv fr = clamp_lanes(splat(0.5f) * (rs * rs + rp * rp), zero, one);
  fr = select((sin2_t >= one) | (ds <= zero) | (dp <= zero), one, fr);  // total internal reflection, grazing
  fr = select(eta == one, zero, fr);                                     // index-matched

  // detail::refract(d, n, eta, t), kept where fr < 1 and t leaves below the geometric surface.
  const Fv rci = clamp_lanes(-dn, minus_one, one);
  const Fv rsin2_t = eta2 * max0(one - rci * rci);
  const Fv k = eta * rci - sqrt_lanes(one - rsin2_t);
  Fv tx = dx * eta + nx * k, ty = dy * eta + ny * k, tz = dz * eta + nz * k;
  normalize_lanes(tx, ty, tz);
  const Iv ok = (fr < one) & ~(rsin2_t >= one) & (tx * gx + ty * gy + tz * gz < zero);

  // reflect(d, n), or reflect(d, g) where that would dip below the geometric surface; normalised.
  const Fv sn = splat(2.0f) * dn;
  Fv mx = dx - nx * sn, my = dy - ny * sn, mz = dz - nz * sn;
  const Fv sg = splat(2.0f) * (dx * gx + dy * gy + dz * gz);
  const Iv below = mx * gx + my * gy + mz * gz <= zero;
  mx = select(below, dx - gx * sg, mx), my = select(below, dy - gy * sg, my), mz = select(below, dz - gz * sg, mz);
  normalize_lanes(mx, my, mz);

  const Fv px = in(kBouncePx), py = in(kBouncePy), pz = in(kBouncePz);
  out(kBounceAx, offset_lanes(px, gx)), out(kBounceAy, offset_lanes(py, gy)), out(kBounceAz, offset_lanes(pz, gz));
  out(kBounceBx, offset_lanes(px, -gx)), out(kBounceBy, offset_lanes(py, -gy)), out(kBounceBz, offset_lanes(pz, -gz));

  out(kBounceFr, fr);
  out(kBounceOk, ok);
  out(kBounceTx, tx), out(kBounceTy, ty), out(kBounceTz, tz);
  out(kBounceMx, mx), out(kBounceMy, my), out(kBounceMz, mz);
}

}  // namespace specula::render
