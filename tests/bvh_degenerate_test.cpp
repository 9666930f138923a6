// The BVH build's reference pass decides in SSE2 which triangles are degenerate (no surface:
// they get no reference, so no structure can report a hit on them). It is documented to compute
// exactly the floats of accel::is_degenerate, the predicate the brute-force twin and the hit
// normal use; these tests compare the two directly, on triangles at the edges of that predicate,
// through both code paths of the pass (the serial one that compacts as it goes, and the parallel
// one that flags and compacts afterwards). Owner: accel.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include "accel/triangles.h"
#include "accel_test_util.h"
#include "specula/accel.h"
#include "specula/bvh.h"

namespace specula {
namespace {

/// Triangles whose squared cross product lies near 0, near the smallest subnormal, near the
/// overflow to infinity, or is exactly zero (collinear, coincident vertices), at magnitudes
/// from 2^-70 to 2^60, plus ordinary ones; each vertex has its own three floats.
test::Mesh edge_of_degeneracy_soup(int count, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> unit(-1.0f, 1.0f);
  std::uniform_int_distribution<int> kind(0, 6), exponent(-70, 60);
  test::Mesh m;
  const auto vec = [&] { return Vec3{unit(rng), unit(rng), unit(rng)}; };
  for (int t = 0; t < count; ++t) {
    const Vec3 base = vec() * std::ldexp(1.0f, exponent(rng) / 2);
    Vec3 a = base, b, c;
    const float s = std::ldexp(1.0f, exponent(rng));  // edge scale
    switch (kind(rng)) {
      case 0:  // collinear: c on the line through a and b (up to the rounding of the products)
        b = a + vec() * s;
        c = a + (b - a) * unit(rng);
        break;
      case 1:  // two vertices equal
        b = a + vec() * s;
        c = b;
        break;
      case 2:  // sliver: c a few ulps off the line a-b
        b = a + vec() * s;
        c = a + (b - a) * 0.5f;
        c.y = std::nextafter(c.y, kInf);
        break;
      case 3:  // squared cross product near the subnormal range: edges about 2^-37
        b = a + vec() * std::ldexp(1.0f, -37 + exponent(rng) % 3);
        c = a + vec() * std::ldexp(1.0f, -38 + exponent(rng) % 3);
        break;
      case 4:  // squared cross product near overflow: edges about 2^31..2^32
        a = vec();
        b = a + vec() * std::ldexp(1.0f, 31 + exponent(rng) % 2);
        c = a + vec() * std::ldexp(1.0f, 31 + exponent(rng) % 2);
        break;
      case 5:  // a vertex at the float range's end
        b = a + vec() * s;
        c = Vec3{std::numeric_limits<float>::max() * unit(rng), unit(rng), unit(rng)};
        break;
      default:  // ordinary
        b = a + vec() * s;
        c = a + vec() * s;
        break;
    }
    for (const Vec3& p : {a, b, c}) {
      m.indices.push_back(static_cast<uint32_t>(m.positions.size()));
      m.positions.push_back(p);
    }
  }
  return m;
}

/// The scene triangles a BVH keeps (every one it can report), sorted.
std::vector<uint32_t> kept(const Bvh& bvh) {
  std::vector<uint32_t> ids(bvh.prim_ids().begin(), bvh.prim_ids().end());
  std::sort(ids.begin(), ids.end());
  return ids;
}

TEST(BvhDegenerate, ReferencePassKeepsExactlyTheTrianglesIsDegenerateKeeps) {
  // 3,000 triangles take the serial pass; 40,000 on two threads the parallel one (more than
  // the builder's task threshold of 4,096).
  for (const int count : {3000, 40000}) {
    const test::Mesh m = edge_of_degeneracy_soup(count, 7u + static_cast<uint32_t>(count));
    std::vector<uint32_t> expected;
    size_t degenerate = 0;
    for (size_t t = 0; t < m.triangle_count(); ++t) {
      const Vec3& a = m.positions[m.indices[3 * t]];
      const Vec3& b = m.positions[m.indices[3 * t + 1]];
      const Vec3& c = m.positions[m.indices[3 * t + 2]];
      if (accel::is_degenerate(a, b, c)) {
        ++degenerate;
      } else {
        expected.push_back(static_cast<uint32_t>(t));
      }
    }
    // The soup must really exercise both sides of the predicate.
    ASSERT_GT(degenerate, m.triangle_count() / 10) << count;
    ASSERT_GT(expected.size(), m.triangle_count() / 3) << count;
    for (const int threads : {1, 2}) {
      BvhOptions o;
      o.threads = threads;
      const Bvh bvh = Bvh::build(m.input(), o);
      EXPECT_EQ(kept(bvh), expected) << count << " triangles, " << threads << " thread(s)";
    }
  }
}

// The same soups span magnitudes up to 2^60, so SAH costs summed over big subtrees overflow to
// inf: the wide collapse used to find no finite split at such a node and crashed (recursing on
// zero slots until the stack ran out). Every kernel must build them and agree with brute force.
TEST(BvhDegenerate, OverflowingSahCostsStillBuildEveryKernelAndMatchBruteForce) {
  const test::Mesh m = edge_of_degeneracy_soup(3000, 3007u);
  const std::vector<Ray> rays = test::make_oracle_rays(m.bounds(), m.positions, 4000, 11u);
  const auto brute = build_tracer(AccelKind::Brute, m.input());
  std::vector<Hit> want(rays.size()), got(rays.size());
  brute->intersect(rays, want);
  const auto hits = std::count_if(want.begin(), want.end(), [](const Hit& h) { return h.hit(); });
  ASSERT_GT(hits, 100) << "the rays must find triangles";
  for (const BvhKernel kernel : test::test_kernels()) {
    BvhOptions o;
    o.kernel = kernel;
    const auto bvh = build_tracer(AccelKind::Bvh, m.input(), o);
    bvh->intersect(rays, got);
    size_t mismatches = 0;
    for (size_t i = 0; i < rays.size(); ++i)
      mismatches += got[i].prim != want[i].prim || std::memcmp(&got[i].t, &want[i].t, sizeof(float)) != 0;
    EXPECT_EQ(mismatches, 0u) << bvh_kernel_name(kernel);
  }
}

}  // namespace
}  // namespace specula
