/// \file fresnel.h
/// Inline bodies of fresnel_dielectric and refract (render.h), for the integrator's per-hit
/// calls (internal to src/render; the public functions in fresnel.cpp call these).
#pragma once

#include <algorithm>
#include <cmath>

#include "specula/math.h"

namespace specula::detail {

inline float fresnel_dielectric(float cos_i, float eta) {
  // Exact unpolarised Fresnel equations for a dielectric interface (e.g. Born & Wolf,
  // pbrt-v4 FrDielectric): the mean of the s- and p-polarised reflectances.
  if (eta == 1.0f) return 0.0f;  // index-matched: no interface (exactly, not 1e-15)
  cos_i = std::clamp(cos_i, 0.0f, 1.0f);
  const float sin2_i = std::max(0.0f, 1.0f - cos_i * cos_i);
  const float sin2_t = eta * eta * sin2_i;
  if (sin2_t >= 1.0f) return 1.0f;  // total internal reflection
  const float cos_t = std::sqrt(std::max(0.0f, 1.0f - sin2_t));
  // With eta = n_i / n_t: r_s = (eta cos_i - cos_t) / (eta cos_i + cos_t),
  // r_p = (cos_i - eta cos_t) / (cos_i + eta cos_t). Both denominators are > 0 unless
  // cos_i = cos_t = 0 (grazing), where the reflectance is 1.
  const float ds = eta * cos_i + cos_t;
  const float dp = cos_i + eta * cos_t;
  if (ds <= 0.0f || dp <= 0.0f) return 1.0f;
  const float rs = (eta * cos_i - cos_t) / ds;
  const float rp = (cos_i - eta * cos_t) / dp;
  return std::clamp(0.5f * (rs * rs + rp * rp), 0.0f, 1.0f);
}

inline bool refract(const Vec3& d, const Vec3& n, float eta, Vec3& out) {
  // Vector form of Snell's law: t = eta d + (eta cos_i - cos_t) n, with cos_i = -dot(d, n).
  const float cos_i = std::clamp(-dot(d, n), -1.0f, 1.0f);
  const float sin2_t = eta * eta * std::max(0.0f, 1.0f - cos_i * cos_i);
  if (sin2_t >= 1.0f) return false;
  const float cos_t = std::sqrt(1.0f - sin2_t);
  out = normalize(d * eta + n * (eta * cos_i - cos_t));
  return true;
}

}  // namespace specula::detail
