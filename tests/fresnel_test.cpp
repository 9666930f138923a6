// Fresnel reflectance and Snell refraction against the textbook formulas; the Blinn-Phong
// power against powf.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <random>

#include "render/phong.h"
#include "specula/render.h"

using namespace specula;

namespace {

/// Transmittance from the Fresnel transmission amplitudes (independent of the reflectance
/// code path): T = (n2 cos_t) / (n1 cos_i) * |t|^2, averaged over s and p polarisation.
double transmittance_from_amplitudes(double cos_i, double n1, double n2) {
  const double sin_i = std::sqrt(std::max(0.0, 1.0 - cos_i * cos_i));
  const double sin_t = n1 / n2 * sin_i;
  if (sin_t >= 1.0) return 0.0;
  const double cos_t = std::sqrt(1.0 - sin_t * sin_t);
  const double ts = 2.0 * n1 * cos_i / (n1 * cos_i + n2 * cos_t);
  const double tp = 2.0 * n1 * cos_i / (n2 * cos_i + n1 * cos_t);
  const double factor = (n2 * cos_t) / (n1 * cos_i);
  return 0.5 * factor * (ts * ts + tp * tp);
}

const double kIors[][2] = {{1.0, 1.5}, {1.5, 1.0}, {1.0, 1.33}, {1.33, 1.0}, {1.33, 1.5},
                           {1.5, 1.33}, {1.0, 2.4}, {2.4, 1.0}, {1.0, 1.0001}};

}  // namespace

TEST(Fresnel, ReflectancePlusAmplitudeTransmittanceIsOne) {
  for (const auto& n : kIors) {
    for (int i = 1; i <= 200; ++i) {
      const double cos_i = i / 200.0;
      const float r = fresnel_dielectric(static_cast<float>(cos_i), static_cast<float>(n[0] / n[1]));
      const double t = transmittance_from_amplitudes(cos_i, n[0], n[1]);
      // float eta and float arithmetic: near grazing R changes fast with the angle.
      EXPECT_NEAR(r + t, 1.0, cos_i < 0.05 ? 1e-4 : 2e-5) << "n1=" << n[0] << " n2=" << n[1] << " cos_i=" << cos_i;
      EXPECT_GE(r, 0.0f);
      EXPECT_LE(r, 1.0f);
    }
  }
}

TEST(Fresnel, NormalIncidenceMatchesClosedForm) {
  for (const auto& n : kIors) {
    const double expected = std::pow((n[0] - n[1]) / (n[0] + n[1]), 2.0);
    EXPECT_NEAR(fresnel_dielectric(1.0f, static_cast<float>(n[0] / n[1])), expected, 1e-6);
  }
  EXPECT_NEAR(fresnel_dielectric(1.0f, 1.0f / 1.5f), 0.04, 1e-6);
  EXPECT_FLOAT_EQ(fresnel_dielectric(0.3f, 1.0f), 0.0f);  // no interface, no reflection
}

TEST(Fresnel, GrazingIncidenceReflectsEverything) {
  EXPECT_NEAR(fresnel_dielectric(0.0f, 1.0f / 1.5f), 1.0f, 1e-6);
  EXPECT_GT(fresnel_dielectric(0.01f, 1.0f / 1.5f), 0.9f);
}

TEST(Fresnel, TotalInternalReflectionAboveCriticalAngle) {
  for (double n1 : {1.33, 1.5, 2.4}) {
    const double eta = n1 / 1.0;
    const double sin_c = 1.0 / eta;
    const double theta_c = std::asin(sin_c);
    for (double delta : {0.002, 0.05, 0.3}) {
      const double above = theta_c + delta, below = theta_c - delta;
      // Above the critical angle: R = 1 and refract reports failure.
      EXPECT_FLOAT_EQ(fresnel_dielectric(static_cast<float>(std::cos(above)), static_cast<float>(eta)), 1.0f);
      const Vec3 n{0, 0, 1};
      const Vec3 d_above{static_cast<float>(std::sin(above)), 0.0f, -static_cast<float>(std::cos(above))};
      Vec3 t;
      EXPECT_FALSE(refract(d_above, n, static_cast<float>(eta), t)) << "n1=" << n1 << " delta=" << delta;
      // Below it: partial reflection and a refracted ray.
      EXPECT_LT(fresnel_dielectric(static_cast<float>(std::cos(below)), static_cast<float>(eta)), 1.0f);
      const Vec3 d_below{static_cast<float>(std::sin(below)), 0.0f, -static_cast<float>(std::cos(below))};
      EXPECT_TRUE(refract(d_below, n, static_cast<float>(eta), t)) << "n1=" << n1 << " delta=" << delta;
    }
  }
}

TEST(Fresnel, ReciprocityBetweenTheTwoSides) {
  // The reflectance is the same seen from either side for the same pair of angles.
  const double n1 = 1.0, n2 = 1.5;
  for (int i = 1; i < 100; ++i) {
    const double cos_i = i / 100.0;
    const double sin_t = n1 / n2 * std::sqrt(1.0 - cos_i * cos_i);
    const double cos_t = std::sqrt(1.0 - sin_t * sin_t);
    EXPECT_NEAR(fresnel_dielectric(static_cast<float>(cos_i), static_cast<float>(n1 / n2)),
                fresnel_dielectric(static_cast<float>(cos_t), static_cast<float>(n2 / n1)), 5e-5);
  }
}

TEST(Refract, SnellsLawAndCoplanarity) {
  const Vec3 normals[] = {{0, 0, 1}, {0, 1, 0}, normalize(Vec3{1, 2, 3}), normalize(Vec3{-0.3f, 0.1f, -0.9f})};
  for (const Vec3& n : normals) {
    Vec3 t1, t2;
    orthonormal_basis(n, t1, t2);
    for (const auto& ior : kIors) {
      const float eta = static_cast<float>(ior[0] / ior[1]);
      for (int a = 0; a < 24; ++a)
        for (int b = 0; b < 8; ++b) {
          const float theta = 1.5f * static_cast<float>(a) / 24.0f;  // up to ~86 degrees
          const float phi = 2.0f * kPi * static_cast<float>(b) / 8.0f;
          const Vec3 tangent = t1 * std::cos(phi) + t2 * std::sin(phi);
          const Vec3 d = normalize(tangent * std::sin(theta) - n * std::cos(theta));
          Vec3 t;
          if (!refract(d, n, eta, t)) {
            EXPECT_GT(eta * std::sin(theta), 0.999f) << "refract failed below the critical angle";
            continue;
          }
          EXPECT_NEAR(length(t), 1.0f, 1e-5f);
          EXPECT_LT(dot(t, n), 0.0f) << "refracted ray must cross the surface";
          const float sin_i = length(cross(d, n)), sin_t = length(cross(t, n));
          EXPECT_NEAR(ior[0] * sin_i, ior[1] * sin_t, 2e-5) << "Snell's law";
          // d, n and t are coplanar: t has no component along cross(d, n).
          const Vec3 plane_normal = cross(d, n);
          if (length(plane_normal) > 1e-4f) {
            EXPECT_NEAR(dot(normalize(plane_normal), t), 0.0f, 2e-6f);
          }
          // Same tangential direction as the incident ray.
          if (sin_i > 1e-3f) {
            EXPECT_GT(dot(t - n * dot(t, n), d - n * dot(d, n)), 0.0f);
          }
        }
    }
  }
}

TEST(Refract, NormalIncidenceGoesStraightThrough) {
  Vec3 t;
  ASSERT_TRUE(refract({0, 0, -1}, {0, 0, 1}, 1.0f / 1.5f, t));
  EXPECT_NEAR(t.x, 0.0f, 1e-7f);
  EXPECT_NEAR(t.y, 0.0f, 1e-7f);
  EXPECT_NEAR(t.z, -1.0f, 1e-7f);
}

TEST(PhongPower, SquaringMatchesPowfWithinOneUlpAndIsExactAtTheEnds) {
  // Whole exponents go by squaring in double; each result must be within one ulp of powf (both
  // are close to correctly rounded) and almost always equal to it; 0 and 1 map exactly, and
  // powers far below the smallest subnormal round to +0 as powf's do.
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  const uint32_t exponents[] = {1, 2, 3, 7, 16, 30, 60, 127, 400, 1000, 4095, 4096};
  size_t equal = 0, total = 0;
  for (const uint32_t n : exponents) {
    const float e = static_cast<float>(n);
    ASSERT_EQ(whole_exponent(e), n);
    EXPECT_EQ(phong_power(1.0f, e, n), 1.0f);
    EXPECT_EQ(phong_power(0.0f, e, n), 0.0f);
    for (int i = 0; i < 20000; ++i) {
      // Uniform in [0, 1] and crowded towards 1, where the lobe is non-zero.
      const float x = i % 2 == 0 ? u(rng) : 1.0f - std::ldexp(u(rng), -static_cast<int>(i % 24));
      const float want = std::pow(x, e), got = phong_power(x, e, n);
      ASSERT_FALSE(std::signbit(got)) << x << "^" << n;
      if (want == 0.0f) {
        EXPECT_LE(got, std::numeric_limits<float>::denorm_min()) << x << "^" << n;
        continue;
      }
      uint32_t a = 0, b = 0;
      std::memcpy(&a, &want, 4);
      std::memcpy(&b, &got, 4);
      EXPECT_LE(a > b ? a - b : b - a, 1u) << x << "^" << n << ": powf " << want << ", squaring " << got;
      equal += a == b;
      ++total;
    }
  }
  EXPECT_GT(equal, total * 99 / 100);
}

TEST(PhongPower, OtherExponentsAreLeftToPowf) {
  for (const float e : {0.0f, 0.5f, 2.5f, -3.0f, 4097.0f, 1e9f, std::nanf(""), INFINITY})
    EXPECT_EQ(whole_exponent(e), 0u) << e;
  EXPECT_EQ(phong_power(0.7f, 2.5f, 0), std::pow(0.7f, 2.5f));
}
