// The block evaluation of lights (render::LitPoints) against render::sample_light(), the
// one-point formula: the same contributions bit for bit, for every kind of point; and the block
// evaluation of mirror and refraction directions (render::bounce_block()) against
// render::bounce_reference(), the gradient sky's blocks against SkyEval::gradient_t(), and the
// Beer-Lambert exponentials (render::exp_in_place()) against std::exp.
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include "render/bounce.h"
#include "render/exp_lanes.h"
#include "render/lighting.h"
#include "render/sky.h"

using namespace specula;
using render::LitPoint;
using render::LitPoints;

namespace {

Vec3 random_unit(std::mt19937& rng) {
  std::normal_distribution<float> g;
  for (;;) {
    const Vec3 v{g(rng), g(rng), g(rng)};
    if (dot(v, v) > 1e-6f) return normalize(v);
  }
}

/// A point of every kind the integrator shades: normals and view directions at random (the
/// light in front, behind or grazing), with and without a shading normal, zero or non-zero
/// colours, whole exponents 1..4096 and non-whole ones, with and without the powf zero bound.
LitPoint random_point(std::mt19937& rng, size_t i) {
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  LitPoint q;
  q.p = {u(rng) * 4.0f - 2.0f, u(rng) * 4.0f - 2.0f, u(rng) * 4.0f - 2.0f};
  q.ng_f = random_unit(rng);
  q.ns_f = i % 3 == 0 ? q.ng_f : normalize(q.ng_f + random_unit(rng) * 0.3f);
  q.view_dir = random_unit(rng);
  q.weight = {u(rng), u(rng), u(rng)};
  q.kd = i % 7 == 0 ? Vec3{} : Vec3{u(rng), u(rng), u(rng)};
  q.has_spec = i % 5 != 0;
  q.specular = q.has_spec ? Vec3{u(rng), u(rng), u(rng)} : Vec3{};
  static const float kExponents[] = {1, 2, 3, 7, 16, 33, 64, 100, 128, 255, 400, 1000, 4095, 4096, 2.5f, 17.25f};
  q.exponent = kExponents[i % (sizeof kExponents / sizeof kExponents[0])];
  q.phong_int = whole_exponent(q.exponent);
  q.zero_below = i % 2 == 0 ? std::exp2(-160.0f / q.exponent) : 0.0f;
  return q;
}

struct TestLight {
  bool directional;
  Vec3 dir, position, power;
};

/// What sample_light() gives for light \p L at \p q, as the integrator calls it.
bool one_point(const LitPoint& q, const TestLight& L, Vec3& c) {
  if (L.directional) return render::sample_light(q, L.dir, L.power, c);
  const Vec3 to = L.position - q.p;
  const float d2 = dot(to, to);
  if (!(d2 > 0.0f)) return false;
  return render::sample_light(q, to * (1.0f / std::sqrt(d2)), L.power / d2, c);
}

/// The block code as each clone of render_tile compiles it (baseline x86-64, x86-64-v3 = AVX2,
/// x86-64-v4 = AVX-512; flattened, as render_tile is), so every clone this CPU runs is held to
/// sample_light()'s bits. (The x86-64-v3 one once lowered the Phong power's eight-double
/// vectors lane by lane through the stack: same bits, but this checks the bits.)
void evaluate_all(LitPoints& lit, const std::vector<TestLight>& lights) {
  for (size_t li = 0; li < lights.size(); ++li)
    lit.evaluate_light(li, lights[li].directional, lights[li].dir, lights[li].position, lights[li].power);
}
// Through pointers: a 32-byte vector passed by value travels in memory to baseline code and in
// a register to AVX code (GCC's -Wpsabi note), so the clones could not share a signature.
void power(const render::lanes::Fv* x, const render::lanes::Iv* n, render::lanes::Fv* out) {
  *out = render::lit_detail::power_lanes(*x, *n);
}
void bounce_all(float* rows, size_t n) {
  render::for_each_block<render::kBounceRows>(rows, n, render::kBounceInputs, render::bounce_block);
}
void gradient_all(float* rows, size_t n) {
  render::for_each_block<render::kSkyRows>(rows, n, 3, render::gradient_t_block);
}
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
[[gnu::flatten, gnu::target("arch=x86-64-v3")]] void bounce_all_v3(float* rows, size_t n) {
  bounce_all(rows, n);
}
[[gnu::flatten, gnu::target("arch=x86-64-v4")]] void bounce_all_v4(float* rows, size_t n) {
  bounce_all(rows, n);
}
[[gnu::flatten, gnu::target("arch=x86-64-v3")]] void gradient_all_v3(float* rows, size_t n) {
  gradient_all(rows, n);
}
[[gnu::flatten, gnu::target("arch=x86-64-v4")]] void gradient_all_v4(float* rows, size_t n) {
  gradient_all(rows, n);
}
[[gnu::flatten, gnu::target("arch=x86-64-v3")]] void evaluate_all_v3(LitPoints& lit, const std::vector<TestLight>& lights) {
  evaluate_all(lit, lights);
}
[[gnu::flatten, gnu::target("arch=x86-64-v4")]] void evaluate_all_v4(LitPoints& lit, const std::vector<TestLight>& lights) {
  evaluate_all(lit, lights);
}
[[gnu::flatten, gnu::target("arch=x86-64-v3")]] void power_v3(const render::lanes::Fv* x,
                                                               const render::lanes::Iv* n,
                                                               render::lanes::Fv* out) {
  power(x, n, out);
}
[[gnu::flatten, gnu::target("arch=x86-64-v4")]] void power_v4(const render::lanes::Fv* x,
                                                               const render::lanes::Iv* n,
                                                               render::lanes::Fv* out) {
  power(x, n, out);
}
#endif

struct Clone {
  const char* name;
  void (*evaluate)(LitPoints&, const std::vector<TestLight>&);
  void (*power)(const render::lanes::Fv*, const render::lanes::Iv*, render::lanes::Fv*);
  void (*bounce)(float*, size_t);
  void (*gradient)(float*, size_t);
};

/// The clones this CPU can run (the same CPUID tests as render_tile's resolver makes).
std::vector<Clone> clones() {
  std::vector<Clone> c{{"x86-64", &evaluate_all, &power, &bounce_all, &gradient_all}};
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
  if (__builtin_cpu_supports("x86-64-v3")) c.push_back({"x86-64-v3", &evaluate_all_v3, &power_v3, &bounce_all_v3, &gradient_all_v3});
  if (__builtin_cpu_supports("x86-64-v4")) c.push_back({"x86-64-v4", &evaluate_all_v4, &power_v4, &bounce_all_v4, &gradient_all_v4});
#endif
  return c;
}

}  // namespace

TEST(Lighting, BlocksGiveSampleLightsBitsForEveryPoint) {
  std::mt19937 rng(7);
  std::vector<TestLight> lights;
  for (int k = 0; k < 4; ++k) lights.push_back({true, random_unit(rng), {}, {1.0f, 0.9f, 0.8f}});
  for (int k = 0; k < 4; ++k) lights.push_back({false, {}, {static_cast<float>(k) - 1.5f, 2.0f, 0.5f}, {3.0f, 2.0f, 1.0f}});
  LitPoints lit;
  size_t checked = 0, contributing = 0, one_by_one = 0;
  for (const Clone& clone : clones()) {
    SCOPED_TRACE(clone.name);
    for (const size_t n : {size_t{1003}, size_t{8}, size_t{5}, size_t{1003}}) {  // storage reused, shrinking and growing
      std::vector<LitPoint> points;
      for (size_t i = 0; i < n; ++i) points.push_back(random_point(rng, i));
      // Special cases: the view direction equal to a light's direction (a zero half vector), a
      // point light exactly at a point (no direction), a light straight along the normal.
      points[1].view_dir = lights[0].dir;
      points[2].p = lights[5].position;
      points[3].ng_f = points[3].ns_f = lights[1].dir;
      lit.reset(n, lights.size());
      for (size_t i = 0; i < n; ++i) ASSERT_EQ(lit.add(points[i]), i);
      ASSERT_EQ(lit.size(), n);
      clone.evaluate(lit, lights);
      for (size_t i = 0; i < n; ++i) {
        const LitPoint back = lit[i];
        ASSERT_EQ(std::memcmp(&back.p, &points[i].p, sizeof(Vec3)), 0);
        ASSERT_EQ(back.phong_int, points[i].phong_int);
        ASSERT_EQ(back.has_spec, points[i].has_spec);
        ASSERT_EQ(lit.one_by_one(i), points[i].has_spec && points[i].phong_int == 0);
        if (lit.one_by_one(i)) {
          ++one_by_one;
          continue;
        }
        for (size_t li = 0; li < lights.size(); ++li) {
          Vec3 want{}, got{};
          const bool w = one_point(points[i], lights[li], want), g = lit.result(li, i, got);
          ASSERT_EQ(g, w) << "point " << i << " light " << li;
          ++checked;
          if (!w) continue;
          ++contributing;
          ASSERT_EQ(std::memcmp(&got, &want, sizeof(Vec3)), 0)
              << "point " << i << " light " << li << ": " << got.x << " " << got.y << " " << got.z << " vs " << want.x
              << " " << want.y << " " << want.z;
        }
      }
    }
  }
  // Both outcomes were exercised, and the powf points were left to sample_light().
  EXPECT_GT(contributing, checked / 5);
  EXPECT_LT(contributing, checked);
  EXPECT_GT(one_by_one, 0u);
}

TEST(Lighting, BlockPowerIsPhongPowerForEveryWholeExponent) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  using render::lanes::Fv;
  using render::lanes::Iv;
  constexpr auto kMost = static_cast<int32_t>(kMaxSquaringExponent);
  // Lane k raises to min(e + step k, kMost): step 1 gives different exponents per block (the
  // largest last), step 0 one exponent in every lane (a block of hits on one material, which
  // power_lanes() raises with the exponent's bits tested once per block).
  const auto check = [&](const Clone& clone, int32_t e, int32_t step) {
    Fv x;
    Iv n;
    for (int k = 0; k < static_cast<int>(render::kBlock); ++k) {
      x[k] = k == 0 ? 1.0f : (k == 1 ? 0.0f : u(rng));
      n[k] = std::min<int32_t>(e + step * k, kMost);
    }
    Fv p;
    clone.power(&x, &n, &p);
    for (int k = 0; k < static_cast<int>(render::kBlock); ++k) {
      const float want = phong_power(x[k], static_cast<float>(n[k]), static_cast<uint32_t>(n[k]));
      ASSERT_EQ(std::memcmp(&p[k], &want, sizeof want), 0)
          << clone.name << ": " << x[k] << "^" << n[k] << (step == 0 ? " (one exponent per block)" : "");
    }
  };
  for (const Clone& clone : clones()) {
    for (int32_t e = 1; e <= kMost && !HasFatalFailure(); e += static_cast<int32_t>(render::kBlock)) check(clone, e, 1);
    for (int32_t e = 1; e <= kMost && !HasFatalFailure(); ++e) check(clone, e, 0);
  }
}

/// Rows of n items stored block by block (render::block_offset), as the integrator keeps them.
template <int kRows>
struct BlockRows {
  explicit BlockRows(size_t n)
      : rows((n + render::kBlock - 1) / render::kBlock * kRows * render::kBlock, 0.0f) {}
  float& operator()(int r, size_t i) { return rows[render::block_offset<kRows>(r, i)]; }
  std::vector<float> rows;
};

/// Same bits, or both NaN (a NaN direction's payload is not part of the contract: such rays
/// miss; none arises from finite, unit inputs).
::testing::AssertionResult same_bits(float got, float want) {
  if ((std::isnan(got) && std::isnan(want)) || std::memcmp(&got, &want, sizeof got) == 0)
    return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << got << " vs " << want;
}

TEST(Lighting, BounceBlocksGiveTheScalarDirectionsBitForBit) {
  const float kNaN = std::numeric_limits<float>::quiet_NaN();
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  static const float kEta[] = {1.0f, 1.0f / 1.33f, 1.33f, 1.0f / 1.5f, 1.5f, 2.42f, 1.0f / 2.42f, 0.5f};
  size_t refracted = 0, total_reflection = 0, geometric_mirror = 0, nudged = 0;
  for (const Clone& clone : clones()) {
    SCOPED_TRACE(clone.name);
    for (const size_t n : {size_t{4001}, size_t{8}, size_t{3}}) {
      BlockRows<render::kBounceRows> cell(n);
      std::vector<Vec3> d(n), sn(n), g(n), p(n);
      std::vector<float> eta(n);
      for (size_t i = 0; i < n; ++i) {
        // As the integrator records them: unit directions, normals facing the incoming ray (the
        // shading normal bent off the geometric one), and every kind of interface.
        g[i] = random_unit(rng);
        d[i] = random_unit(rng);
        if (dot(d[i], g[i]) > 0.0f) d[i] = -d[i];
        sn[i] = i % 4 == 0 ? g[i] : normalize(g[i] + random_unit(rng) * (i % 3 == 0 ? 1.5f : 0.3f));
        eta[i] = kEta[i % (sizeof kEta / sizeof kEta[0])];
        // Hit points at every scale and sign, near the origin (|p| < 1/32: the absolute nudge)
        // and not, with non-finite coordinates too.
        const float scale = std::ldexp(1.0f, static_cast<int>(i % 23) - 11);
        p[i] = Vec3{u(rng) - 0.5f, u(rng) - 0.5f, u(rng) - 0.5f} * scale;
        if (i % 31 == 9) p[i] = Vec3{kNaN, 0.0f, -kInf};
        if (i % 31 == 10) p[i] = Vec3{-0.0f, 1.0f / 32.0f, -1.0f / 32.0f};
        if (i % 31 == 11) p[i] = Vec3{3e38f, -3e38f, 1e-42f};
        switch (i % 29) {  // the edges of every formula
          case 1: d[i] = -sn[i]; break;                                    // normal incidence
          case 2: d[i] = normalize(cross(sn[i], g[i]) + sn[i] * 1e-8f); break;  // grazing
          case 3: sn[i] = Vec3{}; break;                                   // no normal at all
          case 4: d[i] = Vec3{kNaN, 0.0f, 1.0f}; break;
          case 5: eta[i] = kNaN; break;
          case 6: d[i] = Vec3{kInf, 0.0f, 0.0f}; break;
          case 7: eta[i] = 0.0f; break;
          case 8: d[i] = sn[i]; break;                                     // leaving along the normal
          default: break;
        }
        const float in[render::kBounceInputs] = {d[i].x,  d[i].y, d[i].z, sn[i].x, sn[i].y, sn[i].z, g[i].x,
                                                 g[i].y,  g[i].z, eta[i], p[i].x, p[i].y,  p[i].z};
        for (int r = 0; r < render::kBounceInputs; ++r) cell(r, i) = in[r];
      }
      clone.bounce(cell.rows.data(), n);
      for (size_t i = 0; i < n; ++i) {
        float fr;
        bool ok;
        Vec3 t, mirror, above, below;
        render::bounce_reference(d[i], sn[i], g[i], eta[i], p[i], fr, ok, t, mirror, above, below);
        const auto at = [&](int r) { return cell(r, i); };
        int32_t ok_bits;
        std::memcpy(&ok_bits, &cell(render::kBounceOk, i), sizeof ok_bits);
        ASSERT_TRUE(same_bits(at(render::kBounceFr), fr)) << "hit " << i;
        ASSERT_EQ(ok_bits, ok ? -1 : 0) << "hit " << i;
        if (ok) {
          ++refracted;
          ASSERT_TRUE(same_bits(at(render::kBounceTx), t.x)) << "hit " << i;
          ASSERT_TRUE(same_bits(at(render::kBounceTy), t.y)) << "hit " << i;
          ASSERT_TRUE(same_bits(at(render::kBounceTz), t.z)) << "hit " << i;
        }
        total_reflection += fr == 1.0f;
        geometric_mirror += dot(reflect(d[i], sn[i]), g[i]) <= 0.0f;
        ASSERT_TRUE(same_bits(at(render::kBounceMx), mirror.x)) << "hit " << i;
        ASSERT_TRUE(same_bits(at(render::kBounceMy), mirror.y)) << "hit " << i;
        ASSERT_TRUE(same_bits(at(render::kBounceMz), mirror.z)) << "hit " << i;
        ASSERT_TRUE(same_bits(at(render::kBounceAx), above.x)) << "hit " << i;
        ASSERT_TRUE(same_bits(at(render::kBounceAy), above.y)) << "hit " << i;
        ASSERT_TRUE(same_bits(at(render::kBounceAz), above.z)) << "hit " << i;
        ASSERT_TRUE(same_bits(at(render::kBounceBx), below.x)) << "hit " << i;
        ASSERT_TRUE(same_bits(at(render::kBounceBy), below.y)) << "hit " << i;
        ASSERT_TRUE(same_bits(at(render::kBounceBz), below.z)) << "hit " << i;
        nudged += std::fabs(p[i].x) < 1.0f / 32.0f;
      }
    }
  }
  // Every branch was taken: refraction kept, total internal reflection, the mirror direction
  // about the geometric normal.
  EXPECT_GT(refracted, 100u);
  EXPECT_GT(total_reflection, 100u);
  EXPECT_GT(geometric_mirror, 10u);
  EXPECT_GT(nudged, 100u);  // ray origins moved by the absolute offset near zero, and in ulps
}

TEST(Lighting, GradientSkyBlocksGiveTheScalarBlendBitForBit) {
  const float kNaN = std::numeric_limits<float>::quiet_NaN();
  std::mt19937 rng(13);
  std::uniform_real_distribution<float> u(-2.0f, 2.0f);
  size_t above = 0, below = 0;
  for (const Clone& clone : clones()) {
    SCOPED_TRACE(clone.name);
    for (const size_t n : {size_t{2001}, size_t{8}, size_t{1}}) {
      BlockRows<render::kSkyRows> cell(n);
      std::vector<Vec3> d(n);
      for (size_t i = 0; i < n; ++i) {
        // Unit directions as the integrator's rays have, and what a direction could be besides.
        d[i] = i % 5 == 0 ? Vec3{u(rng), u(rng), u(rng)} : random_unit(rng);
        switch (i % 37) {
          case 1: d[i] = Vec3{0.0f, 1.0f, 0.0f}; break;
          case 2: d[i] = Vec3{0.0f, -1.0f, 0.0f}; break;
          case 3: d[i] = Vec3{1.0f, 0.0f, 0.0f}; break;
          case 4: d[i] = Vec3{}; break;
          case 5: d[i] = Vec3{kNaN, 0.5f, 0.0f}; break;
          case 6: d[i] = Vec3{0.0f, kInf, 0.0f}; break;
          case 7: d[i] = Vec3{1e-30f, 1e-30f, 0.0f}; break;
          default: break;
        }
        cell(0, i) = d[i].x, cell(1, i) = d[i].y, cell(2, i) = d[i].z;
      }
      clone.gradient(cell.rows.data(), n);
      for (size_t i = 0; i < n; ++i) {
        const float want = SkyEval::gradient_t(d[i]);
        ASSERT_TRUE(same_bits(cell(3, i), want)) << "direction " << i;
        (want > 0.0f ? above : below) += 1;
      }
    }
  }
  EXPECT_GT(above, 1000u);
  EXPECT_GT(below, 1000u);
}

// exp_in_place() against std::exp, float by float: every 61st bit pattern of all 2^32 (every
// sign, binade and NaN class, ~70 million floats), the neighbourhoods of the boundaries (|x| =
// 80, where the SIMD path hands over to std::exp; the overflow and underflow limits; zero), and
// the special values, in runs of every length mod 4 starting at every alignment.
TEST(Lighting, ExpLanesGiveStdExpBitForBit) {
  std::vector<float> in;
  for (uint64_t b = 0; b < (uint64_t{1} << 32); b += 61) in.push_back(std::bit_cast<float>(static_cast<uint32_t>(b)));
  for (const float edge : {80.0f, 88.0f, 88.72283f, 103.27893f, 103.97208f, 0x1p-126f, 0x1p-149f, 1.0f})
    for (const float sign : {1.0f, -1.0f}) {
      const uint32_t c = std::bit_cast<uint32_t>(sign * edge);
      for (uint32_t d = 0; d < 4096; ++d) {
        in.push_back(std::bit_cast<float>(c + d));
        in.push_back(std::bit_cast<float>(c - d));
      }
    }
  for (const float v : {0.0f, -0.0f, std::numeric_limits<float>::infinity(), -std::numeric_limits<float>::infinity(),
                        std::numeric_limits<float>::quiet_NaN(), -std::numeric_limits<float>::quiet_NaN(),
                        std::numeric_limits<float>::signaling_NaN()})
    in.push_back(v);
  std::vector<float> out(in);
  render::exp_in_place(out.data(), out.size());
  size_t wrong = 0;
  for (size_t i = 0; i < in.size(); ++i) {
    const float want = std::exp(in[i]);
    const bool same = std::isnan(want) ? std::isnan(out[i]) : std::bit_cast<uint32_t>(want) == std::bit_cast<uint32_t>(out[i]);
    if (!same && ++wrong <= 5)
      ADD_FAILURE() << "exp(" << std::hexfloat << in[i] << ") = " << out[i] << ", std::exp gives " << want;
  }
  EXPECT_EQ(wrong, 0u) << "of " << in.size() << " floats (SIMD path " << (render::exp_lanes_simd() ? "on" : "off") << ")";

  // Short runs at every offset: the four-lane loop's tails and unaligned starts (around -1).
  const size_t near_minus_one = 0xBF800000u / 61;
  for (size_t start = 0; start < 4; ++start)
    for (size_t len = 0; len <= 9; ++len) {
      std::vector<float> x(in.begin() + static_cast<ptrdiff_t>(near_minus_one + start),
                           in.begin() + static_cast<ptrdiff_t>(near_minus_one + start + len));
      std::vector<float> y = x;
      render::exp_in_place(y.data(), len);
      for (size_t i = 0; i < len; ++i) {
        const float want = std::exp(x[i]);
        EXPECT_TRUE(std::isnan(want) ? std::isnan(y[i]) : std::bit_cast<uint32_t>(want) == std::bit_cast<uint32_t>(y[i]))
            << "start " << start << ", length " << len << ", lane " << i;
      }
    }
}
