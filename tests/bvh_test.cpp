// BVH tests: API basics, invalid input, tree invariants, transmittance, robustness, and the
// oracle test against the brute-force tracer on procedural and shipped meshes. Owner: accel.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <limits>
#include <numeric>
#include <random>
#include <span>
#include <sstream>
#include <string>
#include <unordered_map>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "accel/bvh_optimize.h"
#include "accel/triangles.h"
#include "accel/watertight.h"
#include "accel_test_util.h"
#include "specula/accel.h"
#include "specula/bvh.h"
#include "specula/error.h"
#include "specula/load.h"
#include "test_util.h"
#include "ray_test_util.h"

namespace specula {
namespace {

using test::make_ray;
using test::trace1;
using test::transmit1;
using test::describe;

using test::Mesh;
using test::test_kernels;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// ---------------------------------------------------------------------------------------------
// Oracle: BVH against brute force.

/// Traces \p rays through brute force and the BVH, built with each kernel of test_kernels(), (in parallel over ray chunks) and checks:
/// identical hit/miss; bit-identical t; the same triangle, ties in t included, with
/// identical u, v, ng; transmittance of the BVH (all opaque) is 0 exactly when a hit
/// exists in the open interval (tmin, tmax), and equals brute force's on every 8th ray.
void expect_matches_brute(const TriangleInput& input, const std::vector<Ray>& rays, const std::string& base_label,
                          const BvhOptions& base_options = {}) {
  const auto brute = build_tracer(AccelKind::Brute, input);
  const size_t n = rays.size();
  std::vector<Hit> hb(n);
  std::vector<Vec3> tb(n, Vec3{-1.0f, -1.0f, -1.0f});
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 128), [&](const tbb::blocked_range<size_t>& range) {
    const size_t b = range.begin(), len = range.size();
    brute->intersect(std::span<const Ray>(rays).subspan(b, len), std::span<Hit>(hb).subspan(b, len));
    for (size_t i = b; i < b + len; ++i)
      if (i % 8 == 0) brute->transmittance(std::span<const Ray>(&rays[i], 1), std::span<Vec3>(&tb[i], 1));
  });
  // The any-hit check needs the closest hit in the open interval: shrink [tmin, tmax] by an ulp.
  std::vector<Ray> open = rays;
  for (Ray& r : open) {
    r.tmin = std::nextafter(r.tmin, kInf);
    r.tmax = std::nextafter(r.tmax, -kInf);
  }
  for (const BvhKernel kernel : test_kernels()) {
    BvhOptions options = base_options;
    options.kernel = kernel;
    const std::string label = base_label + " [" + bvh_kernel_name(kernel) + "]";
    const auto bvh = build_tracer(AccelKind::Bvh, input, options);
    std::vector<Hit> ha(n), ha_open(n);
    std::vector<Vec3> ta(n);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 128), [&](const tbb::blocked_range<size_t>& range) {
      const size_t b = range.begin(), len = range.size();
      const std::span<const Ray> rs = std::span<const Ray>(rays).subspan(b, len);
      bvh->intersect(rs, std::span<Hit>(ha).subspan(b, len));
      bvh->intersect(std::span<const Ray>(open).subspan(b, len), std::span<Hit>(ha_open).subspan(b, len));
      bvh->transmittance(rs, std::span<Vec3>(ta).subspan(b, len));
    });

    size_t hit_count = 0, mismatches = 0;
    std::string first;
    const auto fail = [&](size_t i, const std::string& what) {
      if (mismatches++ == 0) first = "ray " + std::to_string(i) + " " + describe(rays[i]) + ": " + what;
    };
    for (size_t i = 0; i < n; ++i) {
      const Hit &b = hb[i], &a = ha[i];
      if (b.hit() != a.hit()) {
        fail(i, std::string("brute ") + (b.hit() ? "hits prim " + std::to_string(b.prim) + " at t " + std::to_string(b.t) : "misses") +
                    ", bvh " + (a.hit() ? "hits prim " + std::to_string(a.prim) + " at t " + std::to_string(a.t) : "misses"));
        continue;
      }
      if (b.hit()) {
        ++hit_count;
        // Both run the same watertight test on the same floats: t is bit-identical.
        if (a.t != b.t) {
          fail(i, "t differs: brute " + std::to_string(b.t) + " (prim " + std::to_string(b.prim) + "), bvh " +
                      std::to_string(a.t) + " (prim " + std::to_string(a.prim) + ")");
          continue;
        }
        if (a.prim != b.prim) {
          // Ties in t are decided as brute force decides them (the later triangle in scene
          // order), whatever order the kernel visits the leaves in: always the same triangle.
          const uint32_t* idx = input.indices.data() + 3 * size_t{a.prim};
          float v[9];
          for (int k = 0; k < 3; ++k) {
            const Vec3& p = input.positions[idx[k]];
            v[3 * k] = p.x, v[3 * k + 1] = p.y, v[3 * k + 2] = p.z;
          }
          accel::TriHit th{};
          const accel::WatertightRay wr(rays[i]);
          const bool tie = accel::intersect_watertight(wr, v, rays[i].tmin, rays[i].tmax, th) && th.t == a.t;
          fail(i, std::string(tie ? "tie decided differently" : "different triangle") + ": brute " +
                      std::to_string(b.prim) + ", bvh " + std::to_string(a.prim) + " at t " + std::to_string(a.t));
          continue;
        } else if (a.u != b.u || a.v != b.v || !(a.ng == b.ng)) {
          fail(i, "same triangle, different u/v/ng");
          continue;
        }
        if (!std::isfinite(a.t) || !std::isfinite(a.u) || !std::isfinite(a.v) || !is_finite(a.ng)) {
          fail(i, "non-finite hit record");
          continue;
        }
      }
      const bool blocked = ta[i].x == 0.0f && ta[i].y == 0.0f && ta[i].z == 0.0f;
      const bool unblocked = ta[i].x == 1.0f && ta[i].y == 1.0f && ta[i].z == 1.0f;
      if (!(blocked || unblocked)) {
        fail(i, "opaque scene gave a transmittance other than 0 or 1");
        continue;
      }
      if (blocked != ha_open[i].hit()) {
        fail(i, std::string("transmittance says ") + (blocked ? "blocked" : "clear") + " but closest hit in (tmin, tmax) " +
                    (ha_open[i].hit() ? "exists" : "does not exist"));
        continue;
      }
      if (i % 8 == 0 && !(tb[i] == ta[i])) {
        fail(i, "transmittance differs from brute force");
        continue;
      }
    }
    EXPECT_EQ(mismatches, 0u) << label << ": " << mismatches << " of " << n << " rays differ; first: " << first;
    // The ray mix must actually exercise both hits and misses.
    EXPECT_GT(hit_count, n / 20) << label;
    EXPECT_LT(hit_count, n) << label;
    }
}

TEST(BvhOracle, ProceduralMeshesMatchBruteForce) {
  const Mesh sphere = test::make_sphere(24, 48, 1.5f, {0.2f, -0.1f, 0.3f});
  expect_matches_brute(sphere.input(), test::make_oracle_rays(sphere.bounds(), sphere.positions, 20000, 1), "sphere");
  const Mesh grid = test::make_grid(32, 0.25f, -4.0f, -4.0f, 0.5f);
  expect_matches_brute(grid.input(), test::make_oracle_rays(grid.bounds(), grid.positions, 20000, 2), "grid");
  const Mesh soup = test::make_soup(3000, 3);
  expect_matches_brute(soup.input(), test::make_oracle_rays(soup.bounds(), soup.positions, 20000, 3), "soup");
}

TEST(BvhOracle, BuildOptionsDoNotChangeResults) {
  const Mesh soup = test::make_soup(2000, 7);
  const std::vector<Ray> rays = test::make_oracle_rays(soup.bounds(), soup.positions, 6000, 8);
  for (const int bins : {2, 4, 12, 32, 256})
    for (const int leaf : {1, 4, 16}) {
      BvhOptions o;
      o.bins = bins;
      o.max_leaf_size = leaf;
      o.threads = leaf == 4 ? 1 : 2;
      expect_matches_brute(soup.input(), rays, "soup bins " + std::to_string(bins) + " leaf " + std::to_string(leaf), o);
    }
  BvhOptions tc;
  tc.traversal_cost = 8.0f;  // big leaves
  expect_matches_brute(soup.input(), rays, "soup traversal cost 8", tc);
}

// The single-ray kernels take the slab test's near/far plane offsets from a table row chosen by
// the direction's signs: every row (octant) against brute force, in every kernel.
TEST(BvhOracle, EveryDirectionOctantMatchesBruteForce) {
  const Mesh sphere = test::make_sphere(16, 32, 1.5f, {0.2f, -0.1f, 0.3f});
  const std::vector<Ray> base = test::make_oracle_rays(sphere.bounds(), sphere.positions, 3000, 21);
  BvhOptions o;
  o.packets = false;
  for (unsigned octant = 0; octant < 8; ++octant) {
    std::vector<Ray> rays = base;
    for (Ray& r : rays) {
      r.dir.x = (octant & 1u) ? -std::fabs(r.dir.x) : std::fabs(r.dir.x);
      r.dir.y = (octant & 2u) ? -std::fabs(r.dir.y) : std::fabs(r.dir.y);
      r.dir.z = (octant & 4u) ? -std::fabs(r.dir.z) : std::fabs(r.dir.z);
    }
    expect_matches_brute(sphere.input(), rays, "sphere octant " + std::to_string(octant), o);
  }
}

class BvhOracleMesh : public ::testing::TestWithParam<const char*> {};

TEST_P(BvhOracleMesh, HundredThousandRaysMatchBruteForce) {
  SPECULA_REQUIRE_MESH(path, GetParam());
  const Scene scene = load_obj(path);
  ASSERT_GT(scene.triangle_count(), 0u);
  const TriangleInput input{scene.positions, scene.indices, {}};
  const std::vector<Ray> rays = test::make_oracle_rays(scene.bounds(), scene.positions, 100000, 12345);
  expect_matches_brute(input, rays, GetParam());
}

INSTANTIATE_TEST_SUITE_P(BvhShared, BvhOracleMesh, ::testing::ValuesIn(test::kSharedMeshes), test::mesh_param_name);

// ---------------------------------------------------------------------------------------------
// API basics.

TEST(BvhBasics, ParseAccelKind) {
  EXPECT_EQ(parse_accel_kind("bvh"), AccelKind::Bvh);
  EXPECT_EQ(parse_accel_kind("brute"), AccelKind::Brute);
  try {
    parse_accel_kind("kd-tree");
    FAIL() << "expected specula::Error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("kd-tree"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("bvh"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("brute"), std::string::npos) << e.what();
  }
}

TEST(BvhBasics, SingleTriangleHitRecord) {
  const std::vector<Vec3> p{{-1, -1, 0}, {1, -1, 0}, {0, 1, 0}};
  const std::vector<uint32_t> idx{0, 1, 2};
  for (const AccelKind kind : {AccelKind::Bvh, AccelKind::Brute}) {
    BuildInfo info;
    const auto t = build_tracer(kind, {p, idx, {}}, {}, &info);
    EXPECT_EQ(t->name(), kind == AccelKind::Bvh ? "bvh" : "brute");
    const Hit h = trace1(*t, make_ray({0, 0, 5}, {0, 0, -2}));
    ASSERT_TRUE(h.hit());
    EXPECT_EQ(h.prim, 0u);
    EXPECT_FLOAT_EQ(h.t, 2.5f);  // t in units of |dir|
    EXPECT_FLOAT_EQ(h.u, 0.25f);
    EXPECT_FLOAT_EQ(h.v, 0.5f);
    EXPECT_FLOAT_EQ(h.ng.z, 1.0f);  // winding normal, not flipped towards the ray
    // Back side: same normal.
    const Hit back = trace1(*t, make_ray({0, 0, -5}, {0, 0, 1}));
    ASSERT_TRUE(back.hit());
    EXPECT_FLOAT_EQ(back.ng.z, 1.0f);
    // tmax before the triangle, tmin after it.
    EXPECT_FALSE(trace1(*t, make_ray({0, 0, 5}, {0, 0, -1}, 0.0f, 4.9f)).hit());
    EXPECT_FALSE(trace1(*t, make_ray({0, 0, 5}, {0, 0, -1}, 5.1f)).hit());
    EXPECT_FALSE(trace1(*t, make_ray({2, 0, 5}, {0, 0, -1})).hit());
    EXPECT_GT(info.bytes, 0u);
    EXPECT_EQ(info.bytes, t->memory_bytes());
  }
}

TEST(BvhBasics, PrimIsSceneOrder) {
  // Triangles along x, in scrambled spatial order; each must report its own scene index.
  test::Mesh m;
  const std::vector<int> slots{5, 2, 7, 0, 3, 6, 1, 4, 9, 8};
  for (size_t i = 0; i < slots.size(); ++i) {
    const float x = static_cast<float>(slots[i]) * 3.0f;
    const uint32_t b = static_cast<uint32_t>(m.positions.size());
    m.positions.insert(m.positions.end(), {{x - 1, -1, 0}, {x + 1, -1, 0}, {x, 1, 0}});
    m.indices.insert(m.indices.end(), {b, b + 1, b + 2});
  }
  BvhOptions o;
  o.max_leaf_size = 1;
  const auto t = build_tracer(AccelKind::Bvh, m.input(), o);
  for (size_t i = 0; i < slots.size(); ++i) {
    const float x = static_cast<float>(slots[i]) * 3.0f;
    const Hit h = trace1(*t, make_ray({x, 0, 1}, {0, 0, -1}));
    ASSERT_TRUE(h.hit());
    EXPECT_EQ(h.prim, i);
  }
}

TEST(BvhBasics, EmptySceneMissesEverything) {
  for (const AccelKind kind : {AccelKind::Bvh, AccelKind::Brute}) {
    BuildInfo info;
    const auto t = build_tracer(kind, TriangleInput{}, {}, &info);
    const std::vector<Ray> rays{make_ray({0, 0, 0}, {0, 0, 1}), make_ray({1, 2, 3}, {0, 0, 0}),
                                make_ray({kNaN, 0, 0}, {1, 0, 0})};
    std::vector<Hit> hits(rays.size());
    std::vector<Vec3> tr(rays.size());
    TraceStats stats;
    t->intersect(rays, hits, &stats);
    t->transmittance(rays, tr, &stats);
    for (size_t i = 0; i < rays.size(); ++i) {
      EXPECT_FALSE(hits[i].hit());
      EXPECT_EQ(tr[i], Vec3(1.0f));
    }
    EXPECT_EQ(stats.rays, 2 * rays.size());
    if (kind == AccelKind::Bvh) {
      EXPECT_EQ(info.leaves, 1u);
      EXPECT_EQ(info.sah_cost, 0.0);
    }
  }
}

void expect_build_error(const TriangleInput& input, const std::string& needle) {
  for (const AccelKind kind : {AccelKind::Bvh, AccelKind::Brute}) {
    try {
      build_tracer(kind, input);
      ADD_FAILURE() << "expected specula::Error containing '" << needle << "'";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  }
}

TEST(BvhBasics, InvalidInputThrowsClearErrors) {
  const std::vector<Vec3> p{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  const std::vector<uint32_t> out_of_range{0, 1, 3};
  expect_build_error({p, out_of_range, {}}, "vertex index 3");
  const std::vector<uint32_t> partial{0, 1};
  expect_build_error({p, partial, {}}, "multiple of 3");
  const std::vector<Vec3> nan_p{{0, 0, 0}, {kNaN, 0, 0}, {0, 1, 0}};
  const std::vector<uint32_t> idx{0, 1, 2};
  expect_build_error({nan_p, idx, {}}, "non-finite");
  const std::vector<Vec3> inf_p{{0, 0, 0}, {1, 0, 0}, {0, kInf, 0}};
  expect_build_error({inf_p, idx, {}}, "non-finite");
  const std::vector<Vec3> two_tr{{1, 1, 1}, {1, 1, 1}};
  expect_build_error({p, idx, two_tr}, "transmittance");
  const std::vector<Vec3> neg_tr{{-1, 0, 0}};
  expect_build_error({p, idx, neg_tr}, "transmittance");
  // An unused non-finite vertex is harmless.
  const std::vector<Vec3> unused_nan{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {kNaN, kNaN, kNaN}};
  EXPECT_NO_THROW(build_tracer(AccelKind::Bvh, {unused_nan, idx, {}}));
}

// ---------------------------------------------------------------------------------------------
// Tree invariants.

/// The wide traversal layout (either width) covers the triangles of the binary tree exactly
/// once, each leaf's blocks hold its triangles in order with NaN padding, children inside.
template <class Node>
void check_wide_layout(const Bvh& bvh, std::span<const Node> wide, size_t n) {
  if (n > 0) {
    ASSERT_FALSE(wide.empty());
    std::unordered_map<uint32_t, uint32_t> bvh_index;  // scene index -> BVH order
    for (uint32_t k = 0; k < bvh.prim_ids().size(); ++k) bvh_index[bvh.prim_ids()[k]] = k;
    std::vector<int> in_wide(n, 0);
    std::vector<uint32_t> todo{0};
    size_t visited = 0;
    while (!todo.empty()) {
      const Node& w = wide[todo.back()];
      todo.pop_back();
      ASSERT_LT(++visited, wide.size() + 1) << "wide tree has a cycle";
      for (int i = 0; i < Node::kWidth; ++i) {
        const bool empty = w.b[0][0][i] > w.b[1][0][i];
        if (empty) continue;
        if (w.count[i] > 0) {
          // A leaf: ceil(count / 4) triangle blocks; lane j of the leaf is its j-th triangle,
          // the lanes past count are padding (kNoHit, NaN vertices).
          const auto blocks = bvh.triangle_blocks();
          const uint32_t nblocks = (w.count[i] + 3) / 4;
          ASSERT_LE(size_t{w.child[i]} + nblocks, blocks.size());
          for (uint32_t j = 0; j < 4 * nblocks; ++j) {
            const BvhTriangle4& blk = blocks[w.child[i] + j / 4];
            const uint32_t lane = j % 4, id = blk.index[lane];
            if (j >= w.count[i]) {
              EXPECT_EQ(id, kNoHit);
              for (int k = 0; k < 3; ++k)
                for (int a = 0; a < 3; ++a) EXPECT_TRUE(std::isnan(blk.v[k][a][lane]));
              continue;
            }
            // Lanes carry the scene index (what a hit reports); t is its place in BVH order.
            ASSERT_TRUE(bvh_index.count(id)) << "lane with scene index " << id << " not in the BVH";
            const uint32_t t = bvh_index.at(id);
            ASSERT_LT(t, n);
            ++in_wide[t];
            for (int k = 0; k < 3; ++k) {
              const Vec3 p = bvh.triangles()[t].vertex(k);
              for (int a = 0; a < 3; ++a) {
                EXPECT_EQ(blk.v[k][a][lane], p[a]);
                EXPECT_LE(w.b[0][a][i], p[a]);
                EXPECT_GE(w.b[1][a][i], p[a]);
              }
            }
          }
        } else {
          ASSERT_LT(w.child[i], wide.size());
          ASSERT_NE(w.child[i], 0u);
          todo.push_back(w.child[i]);
        }
      }
    }
    EXPECT_EQ(visited, wide.size());
    EXPECT_TRUE(std::all_of(in_wide.begin(), in_wide.end(), [](int c) { return c == 1; }));
    // Every interior child's box contains the exact box of its subtree's triangles (what a
    // compressed layout with rounded boxes must keep too): nodes come after their parent, so
    // one backward pass.
    std::vector<Aabb> exact(wide.size());
    for (size_t k = wide.size(); k-- > 0;) {
      const Node& w = wide[k];
      for (int i = 0; i < Node::kWidth; ++i) {
        if (w.b[0][0][i] > w.b[1][0][i]) continue;  // empty slot
        Aabb child;
        if (w.count[i] > 0) {
          for (uint32_t j = 0; j < w.count[i]; ++j) {
            const BvhTriangle4& blk = bvh.triangle_blocks()[w.child[i] + j / 4];
            for (int v = 0; v < 3; ++v) child.grow({blk.v[v][0][j % 4], blk.v[v][1][j % 4], blk.v[v][2][j % 4]});
          }
        } else {
          ASSERT_GT(w.child[i], k) << "children follow their parent";
          child = exact[w.child[i]];
        }
        for (int a = 0; a < 3; ++a) {
          EXPECT_LE(w.b[0][a][i], child.min[a]) << "node " << k << " child " << i << " axis " << a;
          EXPECT_GE(w.b[1][a][i], child.max[a]) << "node " << k << " child " << i << " axis " << a;
        }
        exact[k].grow(child);
      }
    }
  }
}

void check_invariants(const Bvh& bvh, const TriangleInput& input, const BvhOptions& o) {
  const auto nodes = bvh.nodes();
  const auto ids = bvh.prim_ids();
  const size_t all = input.indices.size() / 3;
  // Zero-area triangles are left out of the structure (they can never be hit).
  std::vector<int> expected(all, 1);
  for (size_t i = 0; i < all; ++i) {
    const Vec3 a = input.positions[input.indices[3 * i]], b = input.positions[input.indices[3 * i + 1]],
               c = input.positions[input.indices[3 * i + 2]];
    const float d = dot(cross(b - a, c - a), cross(b - a, c - a));
    expected[i] = (d > 0.0f && d < kInf) ? 1 : 0;
  }
  const size_t n = static_cast<size_t>(std::count(expected.begin(), expected.end(), 1));
  ASSERT_EQ(ids.size(), n);
  ASSERT_EQ(bvh.triangles().size(), n);
  std::vector<int> seen(all, 0);
  for (const uint32_t id : ids) {
    ASSERT_LT(id, all);
    ++seen[id];
  }
  EXPECT_EQ(seen, expected) << "prim_ids is not a permutation of the non-degenerate triangles";
  // Triangles are stored in BVH order.
  for (size_t i = 0; i < n; ++i)
    for (int k = 0; k < 3; ++k)
      ASSERT_EQ(bvh.triangles()[i].vertex(k), input.positions[input.indices[3 * size_t{ids[i]} + static_cast<size_t>(k)]]);

  // Walk the tree from the root: every triangle in exactly one leaf, children inside parents.
  const auto contains = [](const BvhNode& outer, Vec3 lo, Vec3 hi) {
    return outer.min.x <= lo.x && outer.min.y <= lo.y && outer.min.z <= lo.z && outer.max.x >= hi.x &&
           outer.max.y >= hi.y && outer.max.z >= hi.z;
  };
  std::vector<int> in_leaf(n, 0);
  size_t leaves = 0, interior = 0;
  uint32_t max_depth = 0;
  double sah = 0.0;
  const auto half_area = [](const BvhNode& nd) {
    const Vec3 e = nd.max - nd.min;
    return double{e.x} * e.y + double{e.y} * e.z + double{e.z} * e.x;
  };
  std::vector<std::pair<uint32_t, uint32_t>> stack{{0, 0}};
  while (!stack.empty()) {
    const auto [index, depth] = stack.back();
    stack.pop_back();
    ASSERT_LT(index, nodes.size());
    const BvhNode& nd = nodes[index];
    max_depth = std::max(max_depth, depth);
    if (nd.is_leaf()) {
      ++leaves;
      sah += half_area(nd) * nd.count;
      EXPECT_LE(nd.count, static_cast<uint32_t>(o.max_leaf_size)) << "leaf " << index;
      ASSERT_LE(size_t{nd.left_first} + nd.count, n);
      for (uint32_t i = nd.left_first; i < nd.left_first + nd.count; ++i) {
        ++in_leaf[i];
        const BvhTriangle& t = bvh.triangles()[i];
        for (int k = 0; k < 3; ++k) EXPECT_TRUE(contains(nd, t.vertex(k), t.vertex(k))) << "leaf " << index;
      }
    } else {
      ++interior;
      sah += half_area(nd) * o.traversal_cost;
      ASSERT_GE(nd.left_first, 2u);
      ASSERT_EQ(nd.left_first % 2, 0u) << "sibling pairs must be cache-line aligned";
      ASSERT_LT(nd.left_first + 1, nodes.size());
      for (uint32_t c = nd.left_first; c <= nd.left_first + 1; ++c) {
        EXPECT_TRUE(contains(nd, nodes[c].min, nodes[c].max)) << "child " << c << " of " << index;
        stack.push_back({c, depth + 1});
      }
    }
  }
  EXPECT_TRUE(std::all_of(in_leaf.begin(), in_leaf.end(), [](int c) { return c == 1; }));

  // The wide layout of the BVH's kernel is filled, the other one is empty.
  EXPECT_NE(bvh.kernel(), BvhKernel::Auto);
  EXPECT_EQ(bvh.kernel(), resolve_bvh_kernel(o.kernel));
  const int filled = !bvh.wide_nodes().empty() + !bvh.wide8_nodes().empty() + !bvh.wide16_nodes().empty();
  EXPECT_EQ(filled, n > 0 ? 1 : 0);
  if (bvh.kernel() == BvhKernel::Avx512x16) {
    check_wide_layout(bvh, bvh.wide16_nodes(), n);
  } else if (bvh_kernel_is_8_wide(bvh.kernel())) {
    check_wide_layout(bvh, bvh.wide8_nodes(), n);
  } else {
    check_wide_layout(bvh, bvh.wide_nodes(), n);
  }
  const BuildInfo& info = bvh.build_info();
  EXPECT_EQ(info.leaves, leaves);
  EXPECT_EQ(info.nodes, leaves + interior);
  EXPECT_EQ(info.max_depth, max_depth);
  EXPECT_LE(max_depth, 100u);
  if (half_area(nodes[0]) > 0.0) {
    EXPECT_NEAR(info.sah_cost, sah / half_area(nodes[0]), 1e-6 * info.sah_cost);
  }
  EXPECT_EQ(info.bytes, bvh.memory_bytes());
  EXPECT_GE(info.build_ms, 0.0);
  // Node 0 bounds every triangle in the structure.
  for (const BvhTriangle& t : bvh.triangles())
    for (int k = 0; k < 3; ++k) EXPECT_TRUE(contains(nodes[0], t.vertex(k), t.vertex(k)));
}

TEST(BvhStructure, InvariantsHoldForProceduralMeshes) {
  const Mesh soup = test::make_soup(5000, 11);
  const Mesh sphere = test::make_sphere(40, 80);
  for (const BvhKernel kernel : test_kernels()) {
    for (const int leaf : {1, 2, 16}) {
      BvhOptions o;
      o.max_leaf_size = leaf;
      o.kernel = kernel;
      const Bvh bvh = Bvh::build(soup.input(), o);
      check_invariants(bvh, soup.input(), o);
    }
    BvhOptions o;
    o.kernel = kernel;
    const Bvh bvh = Bvh::build(sphere.input(), o);
    check_invariants(bvh, sphere.input(), o);
  }
}

TEST(BvhBasics, KernelNamesAndSupport) {
  EXPECT_EQ(parse_bvh_kernel("auto"), BvhKernel::Auto);
  EXPECT_EQ(parse_bvh_kernel("sse4"), BvhKernel::Sse4);
  EXPECT_EQ(parse_bvh_kernel("avx2x8"), BvhKernel::Avx2x8);
  for (const BvhKernel k : {BvhKernel::Auto, BvhKernel::Sse4, BvhKernel::Avx2x8, BvhKernel::Avx512x8, BvhKernel::Avx512x16})
    EXPECT_EQ(parse_bvh_kernel(bvh_kernel_name(k)), k);
  try {
    parse_bvh_kernel("avx512");
    FAIL() << "unknown kernel accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("sse4"), std::string::npos) << e.what();
  }
  EXPECT_TRUE(bvh_kernel_supported(BvhKernel::Sse4));
  EXPECT_NE(resolve_bvh_kernel(BvhKernel::Auto), BvhKernel::Auto);
  EXPECT_EQ(resolve_bvh_kernel(BvhKernel::Sse4), BvhKernel::Sse4);
  // Auto takes the widest kernel the CPU runs.
  EXPECT_EQ(resolve_bvh_kernel(BvhKernel::Auto),
            bvh_kernel_supported(BvhKernel::Avx512x16) ? BvhKernel::Avx512x16
            : bvh_kernel_supported(BvhKernel::Avx2x8) ? BvhKernel::Avx2x8
                                                      : BvhKernel::Sse4);
  // A kernel needing more than AVX2 is never supported where AVX2 is missing.
  if (!bvh_kernel_supported(BvhKernel::Avx2x8)) {
    EXPECT_FALSE(bvh_kernel_supported(BvhKernel::Avx512x8));
    EXPECT_FALSE(bvh_kernel_supported(BvhKernel::Avx512x16));
  }
}

TEST(BvhStructure, InvariantsAndQualityOnBunny) {
  SPECULA_REQUIRE_MESH(path, "stanford-bunny.obj");
  const Scene scene = load_obj(path);
  const TriangleInput input{scene.positions, scene.indices, {}};
  BvhOptions o;
  const Bvh bvh = Bvh::build(input, o);
  check_invariants(bvh, input, o);
  const BuildInfo& info = bvh.build_info();
  // SAH termination must produce small leaves on a dense scan (not one giant leaf, not one
  // triangle everywhere) and a far better cost than a single leaf (= triangle count).
  const double tris_per_leaf = static_cast<double>(scene.triangle_count()) / static_cast<double>(info.leaves);
  EXPECT_GT(tris_per_leaf, 1.0);
  EXPECT_LT(tris_per_leaf, 6.0);
  EXPECT_LT(info.sah_cost, 100.0);
  EXPECT_LT(info.max_depth, 40u);
}

TEST(BvhStructure, SameTreeForAnyThreadCount) {
  const Mesh soup = test::make_soup(40000, 5);  // above the task threshold, so tasks really run
  BvhOptions one, two;
  one.threads = 1;
  two.threads = 2;
  const Bvh a = Bvh::build(soup.input(), one), b = Bvh::build(soup.input(), two);
  EXPECT_TRUE(std::equal(a.prim_ids().begin(), a.prim_ids().end(), b.prim_ids().begin(), b.prim_ids().end()));
  EXPECT_EQ(a.build_info().nodes, b.build_info().nodes);
  ASSERT_EQ(a.nodes().size(), b.nodes().size());
  for (size_t i = 0; i < a.nodes().size(); ++i) {
    const BvhNode &x = a.nodes()[i], &y = b.nodes()[i];
    ASSERT_TRUE(x.min == y.min && x.max == y.max && x.left_first == y.left_first && x.count == y.count) << "node " << i;
  }
  EXPECT_EQ(a.build_info().sah_cost, b.build_info().sah_cost);  // summed in tree order: exact
  EXPECT_EQ(a.build_info().max_depth, b.build_info().max_depth);
  check_invariants(b, soup.input(), two);
}

TEST(BvhStructure, SameTraversalLayoutForAnyThreadCount) {
  // Not only the binary tree: the wide nodes of every kernel, the triangle blocks and the
  // triangles are byte for byte the same whether the build used one thread or two.
  const Mesh soup = test::make_soup(40000, 5), other = test::make_soup(40000, 6);
  for (const BvhKernel k : test_kernels()) {
    BvhOptions one, two;
    one.threads = 1;
    two.threads = 2;
    one.kernel = two.kernel = k;
    const Bvh a = Bvh::build(soup.input(), one);
    // Another tree in between: the builder reuses its scratch tables between builds, and a
    // two-thread pass that read an entry before writing it would find the same soup's values.
    (void)Bvh::build(other.input(), two);
    const Bvh b = Bvh::build(soup.input(), two);
    // (memcmp of the empty layouts' null pointers would be undefined, even for 0 bytes.)
    const auto same_bytes = [](auto x, auto y) {
      return x.size() == y.size() && (x.empty() || std::memcmp(x.data(), y.data(), x.size_bytes()) == 0);
    };
    EXPECT_TRUE(same_bytes(a.wide_nodes(), b.wide_nodes())) << bvh_kernel_name(k);
    EXPECT_TRUE(same_bytes(a.wide8_nodes(), b.wide8_nodes())) << bvh_kernel_name(k);
    EXPECT_TRUE(same_bytes(a.wide16_nodes(), b.wide16_nodes())) << bvh_kernel_name(k);
    EXPECT_TRUE(same_bytes(a.triangle_blocks(), b.triangle_blocks())) << bvh_kernel_name(k);
    EXPECT_TRUE(same_bytes(a.triangles(), b.triangles())) << bvh_kernel_name(k);
  }
}

TEST(BvhStructure, SahCostDoesNotRiseAboveRecordedBounds) {
  // The build may get faster, never worse trees: SAH costs as recorded on 2026-12-02 (binned
  // SAH, 4 + n / 20 bins up to 32), plus a relative 1e-9 for the summation.
  const std::pair<int, double> soups[] = {{3000, 102.08646495078148}, {40000, 677.07695933820719}};
  for (const auto& [count, bound] : soups) {
    const Mesh soup = test::make_soup(count, count == 3000 ? 9u : 5u);
    for (const int threads : {1, 2}) {
      BvhOptions o;
      o.threads = threads;
      EXPECT_LE(Bvh::build(soup.input(), o).build_info().sah_cost, bound * (1.0 + 1e-9)) << count << " triangles";
    }
  }
  SPECULA_REQUIRE_MESH(path, "stanford-bunny.obj");
  const Scene scene = load_obj(path);
  // Leaves of at most 16 triangles (the default until 2026-12-07), and of at most 8 (since).
  BvhOptions sixteen;
  sixteen.max_leaf_size = 16;
  EXPECT_LE(Bvh::build({scene.positions, scene.indices, {}}, sixteen).build_info().sah_cost, 36.4980 + 1e-4);
  EXPECT_LE(Bvh::build({scene.positions, scene.indices, {}}).build_info().sah_cost, 36.2837 + 1e-4);
}

TEST(BvhBasics, TrianglesAreCopiedOutOnceAndSharedByCopies) {
  // triangles() is filled from the blocks on its first call: concurrent first calls, and a
  // copy of the Bvh made before it, all see the same, complete array in BVH order.
  const Mesh soup = test::make_soup(5000, 3);
  const Bvh bvh = Bvh::build(soup.input());
  const Bvh copy = bvh;  // NOLINT(performance-unnecessary-copy-initialization): the copy is the test
  std::atomic<int> wrong{0};
  tbb::parallel_for(tbb::blocked_range<int>(0, 16, 1), [&](const tbb::blocked_range<int>& r) {
    for (int i = r.begin(); i != r.end(); ++i) {
      const std::span<const BvhTriangle> t = (i % 2 ? copy : bvh).triangles();
      if (t.size() != bvh.prim_ids().size()) {
        ++wrong;
        continue;
      }
      for (size_t j = 0; j < t.size(); ++j)
        for (int k = 0; k < 3; ++k)
          if (!(t[j].vertex(k) == soup.positions[soup.indices[3 * size_t{bvh.prim_ids()[j]} + static_cast<size_t>(k)]])) ++wrong;
    }
  });
  EXPECT_EQ(wrong.load(), 0);
  EXPECT_EQ(bvh.triangles().data(), copy.triangles().data());
  EXPECT_TRUE(Bvh().triangles().empty());
}

TEST(BvhStructure, RebuildsAndConcurrentBuildsGiveTheSameTree) {
  // Builds reuse their calling thread's scratch memory: a smaller build after a larger one
  // (stale contents beyond its size), a larger one after it (regrown), and builds running
  // concurrently on TBB's threads (each thread's own scratch) must all give the fresh trees.
  const Mesh big = test::make_soup(40000, 5), small = test::make_soup(3000, 9);
  BvhOptions o;
  o.threads = 2;
  const Bvh ref_big = Bvh::build(big.input(), o), ref_small = Bvh::build(small.input(), o);
  const auto same = [](const Bvh& a, const Bvh& b) {
    if (a.nodes().size() != b.nodes().size() || a.build_info().sah_cost != b.build_info().sah_cost) return false;
    for (size_t i = 0; i < a.nodes().size(); ++i) {
      const BvhNode &x = a.nodes()[i], &y = b.nodes()[i];
      if (!(x.min == y.min && x.max == y.max && x.left_first == y.left_first && x.count == y.count)) return false;
    }
    return std::equal(a.prim_ids().begin(), a.prim_ids().end(), b.prim_ids().begin(), b.prim_ids().end());
  };
  EXPECT_TRUE(same(Bvh::build(small.input(), o), ref_small));
  EXPECT_TRUE(same(Bvh::build(big.input(), o), ref_big));
  std::atomic<int> wrong{0};
  tbb::parallel_for(tbb::blocked_range<int>(0, 8, 1), [&](const tbb::blocked_range<int>& r) {
    for (int i = r.begin(); i != r.end(); ++i) {
      BvhOptions one = o;
      one.threads = 1 + i % 2;
      const bool ok = i % 2 ? same(Bvh::build(big.input(), one), ref_big) : same(Bvh::build(small.input(), one), ref_small);
      if (!ok) ++wrong;
    }
  });
  EXPECT_EQ(wrong.load(), 0);
}

TEST(BvhStructure, CoincidentCentroidsRespectMaxLeafSize) {
  // 200 copies of one triangle: no SAH split exists; the builder must still honour
  // max_leaf_size by halving the index range, and every copy stays reachable.
  test::Mesh m;
  m.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  for (int i = 0; i < 200; ++i) m.indices.insert(m.indices.end(), {0, 1, 2});
  BvhOptions o;
  o.max_leaf_size = 4;
  const Bvh bvh = Bvh::build(m.input(), o);
  check_invariants(bvh, m.input(), o);
  const Hit h = bvh.intersect(make_ray({0.25f, 0.25f, 1}, {0, 0, -1}));
  ASSERT_TRUE(h.hit());
  EXPECT_FLOAT_EQ(h.t, 1.0f);
  EXPECT_LT(h.prim, 200u);
  // Only zero-area triangles: an empty structure, nothing to hit, no crash.
  test::Mesh points;
  points.positions = {{0.5f, 0.5f, 0.5f}, {0.6f, 0.6f, 0.6f}};
  for (int i = 0; i < 50; ++i) points.indices.insert(points.indices.end(), {0, 0, 0, 0, 1, 0});
  const Bvh pb = Bvh::build(points.input(), o);
  EXPECT_TRUE(pb.triangles().empty());
  EXPECT_FALSE(pb.intersect(make_ray({0.5f, 0.5f, 0}, {0, 0, 1})).hit());
  EXPECT_FALSE(pb.occluded(make_ray({0.55f, 0.55f, 0.55f}, {1, 1, 1})));
}

TEST(BvhStructure, StatsCountWork) {
  const Mesh sphere = test::make_sphere(16, 32);
  const auto t = build_tracer(AccelKind::Bvh, sphere.input());
  const std::vector<Ray> rays{make_ray({0, 0, 5}, {0, 0, -1}), make_ray({0, 0, 5}, {0, 0, 1})};
  std::vector<Hit> hits(2);
  TraceStats stats;
  t->intersect(rays, hits, &stats);
  EXPECT_EQ(stats.rays, 2u);
  EXPECT_GT(stats.nodes_visited, 1u);
  EXPECT_GT(stats.triangles_tested, 0u);
  EXPECT_LT(stats.triangles_tested, sphere.triangle_count());
  TraceStats shadow;
  std::vector<Vec3> tr(2);
  t->transmittance(rays, tr, &shadow);
  EXPECT_EQ(shadow.rays, 2u);
  EXPECT_GT(shadow.nodes_visited, 0u);
  // Without stats the results are the same.
  std::vector<Hit> plain(2);
  t->intersect(rays, plain);
  EXPECT_EQ(plain[0].prim, hits[0].prim);
  EXPECT_EQ(plain[0].t, hits[0].t);
}

// ---------------------------------------------------------------------------------------------
// Transmittance.

/// Two parallel quads at z = 0 and z = -1 (triangles 0-1 and 2-3) and an opaque quad at z = -2
/// (triangles 4-5) covering only x > 0.
Mesh layered_quads() {
  Mesh m;
  const auto quad = [&m](float x0, float x1, float z) {
    const uint32_t b = static_cast<uint32_t>(m.positions.size());
    m.positions.insert(m.positions.end(), {{x0, -1, z}, {x1, -1, z}, {x1, 1, z}, {x0, 1, z}});
    m.indices.insert(m.indices.end(), {b, b + 1, b + 2, b, b + 2, b + 3});
  };
  quad(-1, 1, 0);
  quad(-1, 1, -1);
  quad(0, 1, -2);
  return m;
}

TEST(BvhTransmittance, ProductOfTransparentLayersAndOpaqueBlocks) {
  const Mesh m = layered_quads();
  const std::vector<Vec3> tr{{0.5f, 0.8f, 1.0f}, {0.5f, 0.8f, 1.0f}, {0.5f, 0.25f, 0.1f},
                             {0.5f, 0.25f, 0.1f}, {0, 0, 0},          {0, 0, 0}};
  for (const AccelKind kind : {AccelKind::Bvh, AccelKind::Brute}) {
    SCOPED_TRACE(kind == AccelKind::Bvh ? "bvh" : "brute");
    const auto t = build_tracer(kind, m.input(tr));
    // x < 0: through both transparent quads only.
    const Vec3 both = transmit1(*t, make_ray({-0.5f, 0.3f, 1}, {0, 0, -1}));
    EXPECT_FLOAT_EQ(both.x, 0.25f);
    EXPECT_FLOAT_EQ(both.y, 0.2f);
    EXPECT_FLOAT_EQ(both.z, 0.1f);
    // tmax respected: stops before the second layer (open interval: t = 2 is excluded too).
    const Vec3 first = transmit1(*t, make_ray({-0.5f, 0.3f, 1}, {0, 0, -1}, 0.0f, 1.5f));
    EXPECT_EQ(first, Vec3(0.5f, 0.8f, 1.0f));
    EXPECT_EQ(transmit1(*t, make_ray({-0.5f, 0.3f, 1}, {0, 0, -1}, 0.0f, 0.5f)), Vec3(1.0f));
    // tmin respected: starts behind the first layer.
    EXPECT_EQ(transmit1(*t, make_ray({-0.5f, 0.3f, 1}, {0, 0, -1}, 1.5f)), Vec3(0.5f, 0.25f, 0.1f));
    // x > 0: the opaque quad blocks everything.
    EXPECT_EQ(transmit1(*t, make_ray({0.5f, 0.3f, 1}, {0, 0, -1})), Vec3(0.0f));
    EXPECT_EQ(transmit1(*t, make_ray({0.5f, 0.3f, 1}, {0, 0, -1}, 0.0f, 2.5f)), Vec3(1.0f) * Vec3(0.25f, 0.2f, 0.1f));
    // Missing everything: exactly 1.
    EXPECT_EQ(transmit1(*t, make_ray({5, 5, 1}, {0, 0, -1})), Vec3(1.0f));
  }
  // No transmittance given: everything opaque.
  const auto opaque = build_tracer(AccelKind::Bvh, m.input());
  EXPECT_EQ(transmit1(*opaque, make_ray({-0.5f, 0.3f, 1}, {0, 0, -1})), Vec3(0.0f));
  EXPECT_EQ(transmit1(*opaque, make_ray({-0.5f, 0.3f, 1}, {0, 0, -1}, 0.0f, 0.9f)), Vec3(1.0f));
}

TEST(BvhTransmittance, ManyLayersMatchBruteForce) {
  // A stack of 64 tinted layers (two triangles each) plus random opaque blockers.
  Mesh m;
  std::vector<Vec3> tr;
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (int l = 0; l < 64; ++l) {
    const float z = -static_cast<float>(l) * 0.1f;
    const float x0 = -1.0f + u(rng) * 0.5f, x1 = 1.0f - u(rng) * 0.5f;
    const uint32_t b = static_cast<uint32_t>(m.positions.size());
    m.positions.insert(m.positions.end(), {{x0, -1, z}, {x1, -1, z}, {x1, 1, z}, {x0, 1, z}});
    m.indices.insert(m.indices.end(), {b, b + 1, b + 2, b, b + 2, b + 3});
    const Vec3 t = (l % 13 == 12) ? Vec3{} : Vec3{0.9f + 0.1f * u(rng), 0.95f, 1.0f};
    tr.insert(tr.end(), {t, t});
  }
  const auto brute = build_tracer(AccelKind::Brute, m.input(tr));
  std::vector<Ray> rays;
  for (int i = 0; i < 2000; ++i)
    rays.push_back(make_ray({u(rng) * 2.4f - 1.2f, u(rng) * 2 - 1, 1}, {u(rng) * 0.2f - 0.1f, 0, -1}, 0.0f, u(rng) * 8.0f));
  std::vector<Vec3> b(rays.size());
  brute->transmittance(rays, b);
  for (const BvhKernel kernel : test_kernels())
    for (const BvhQuality quality : {BvhQuality::Fast, BvhQuality::High}) {
    BvhOptions o;
    o.kernel = kernel;
    o.quality = quality;
    const auto bvh = build_tracer(AccelKind::Bvh, m.input(tr), o);
    std::vector<Vec3> a(rays.size());
    bvh->transmittance(rays, a);
    int partial = 0;
    for (size_t i = 0; i < rays.size(); ++i) {
      // Products over the same factors, multiplied in scene order by both: bit-identical.
      EXPECT_TRUE(a[i] == b[i]) << bvh_kernel_name(kernel) << " " << bvh_quality_name(quality) << " " << describe(rays[i]) << ": bvh (" << a[i].x << ", "
                                << a[i].y << ", " << a[i].z << "), brute (" << b[i].x << ", " << b[i].y << ", " << b[i].z
                                << ")";
      partial += a[i].x > 0.0f && a[i].x < 0.99f;
    }
    EXPECT_GT(partial, 100);
  }
}

// ---------------------------------------------------------------------------------------------
// Robustness.

TEST(BvhRobustness, DegenerateTrianglesAndBadRaysNeverCrashOrNaN) {
  Mesh m = test::make_soup(500, 21);
  // Fully degenerate additions: a point and a line.
  const uint32_t b = static_cast<uint32_t>(m.positions.size());
  m.positions.insert(m.positions.end(), {{0.5f, 0.5f, 0.5f}, {0.2f, 0.2f, 0.2f}, {0.8f, 0.8f, 0.8f}});
  m.indices.insert(m.indices.end(), {b, b, b, b + 1, b, b + 2});
  const std::vector<Ray> bad{
      make_ray({kNaN, 0, 0}, {1, 0, 0}),  make_ray({0.5f, 0.5f, -1}, {kNaN, kNaN, kNaN}),
      make_ray({0.5f, 0.5f, -1}, {0, 0, 0}), make_ray({0.5f, 0.5f, -1}, {0, 0, kInf}),
      make_ray({-kInf, 0.5f, 0.5f}, {1, 0, 0}), make_ray({0.5f, 0.5f, -1}, {0, 0, 1}, 2.0f, 1.0f),
      make_ray({0.5f, 0.5f, -1}, {0, 0, 1}, kNaN, kNaN), make_ray({0.5f, 0.5f, -1}, {0, 0, 1}, -kInf, kInf),
      make_ray({0.5f, 0.5f, -1}, {1e-30f, 1e-30f, 1e-30f}), make_ray({0.5f, 0.5f, -1}, {0, 0, 1e30f}),
      make_ray({0.5f, 0.5f, 0.5f}, {1, 1, 1}),  // through the degenerate point and line
  };
  for (const test::TracerVariant& variant : test::triangle_tracers()) {
    SCOPED_TRACE(variant.name);
    const auto t = build_tracer(variant.kind, m.input(), variant.options);
    std::vector<Hit> hits(bad.size());
    std::vector<Vec3> tr(bad.size());
    t->intersect(bad, hits);
    t->transmittance(bad, tr);
    for (size_t i = 0; i < bad.size(); ++i) {
      SCOPED_TRACE(describe(bad[i]));
      if (hits[i].hit()) {
        EXPECT_TRUE(std::isfinite(hits[i].t));
        EXPECT_TRUE(std::isfinite(hits[i].u) && std::isfinite(hits[i].v));
        EXPECT_TRUE(is_finite(hits[i].ng));
        EXPECT_NEAR(length(hits[i].ng), 1.0f, 1e-5f);
      }
      EXPECT_TRUE(is_finite(tr[i]));
    }
    // Rays with NaN parts or an empty interval miss.
    for (const size_t i : {0u, 1u, 2u, 5u, 6u}) EXPECT_FALSE(hits[i].hit()) << i;
  }
}

TEST(BvhRobustness, HitsAreNeverDegenerateTriangles) {
  Mesh m = test::make_soup(4000, 31);
  const auto t = build_tracer(AccelKind::Bvh, m.input());
  const std::vector<Ray> rays = test::make_oracle_rays(m.bounds(), m.positions, 20000, 32);
  std::vector<Hit> hits(rays.size());
  t->intersect(rays, hits);
  for (size_t i = 0; i < rays.size(); ++i) {
    if (!hits[i].hit()) continue;
    const uint32_t* idx = m.indices.data() + 3 * size_t{hits[i].prim};
    const Vec3 c = cross(m.positions[idx[1]] - m.positions[idx[0]], m.positions[idx[2]] - m.positions[idx[0]]);
    ASSERT_GT(length(c), 0.0f) << "ray " << i << " hit a zero-area triangle";
    ASSERT_NEAR(length(hits[i].ng), 1.0f, 1e-5f);
    ASSERT_GE(hits[i].u, 0.0f);
    ASSERT_GE(hits[i].v, 0.0f);
    ASSERT_LE(hits[i].u + hits[i].v, 1.0f + 1e-5f);
  }
}

TEST(BvhRobustness, SingleRayHelpersMatchBatch) {
  const Mesh sphere = test::make_sphere(12, 24);
  const Bvh bvh = Bvh::build(sphere.input());
  const std::vector<Ray> rays = test::make_oracle_rays(sphere.bounds(), sphere.positions, 500, 4);
  std::vector<Hit> hits(rays.size());
  std::vector<Vec3> tr(rays.size());
  bvh.intersect(rays, hits);
  bvh.transmittance(rays, tr);
  for (size_t i = 0; i < rays.size(); ++i) {
    const Hit h = bvh.intersect(rays[i]);
    EXPECT_EQ(h.prim, hits[i].prim);
    EXPECT_EQ(h.t, hits[i].t);
    EXPECT_EQ(bvh.occluded(rays[i]), tr[i].x == 0.0f);
  }
  EXPECT_EQ(bvh.bounds().min, sphere.bounds().min);
  EXPECT_EQ(bvh.bounds().max, sphere.bounds().max);
}

TEST(BvhRobustness, SpanSizeMismatchThrows) {
  const Mesh sphere = test::make_sphere(4, 8);
  for (const AccelKind kind : {AccelKind::Bvh, AccelKind::Brute}) {
    const auto t = build_tracer(kind, sphere.input());
    const std::vector<Ray> rays(3);
    std::vector<Hit> hits(2);
    std::vector<Vec3> tr(1);
    EXPECT_THROW(t->intersect(rays, hits), Error);
    EXPECT_THROW(t->transmittance(rays, tr), Error);
  }
}

// Leaves of hundreds of triangles (more than a compressed child word could count), and flat
// axis-aligned geometry far from the origin and tiny: the wide layouts keep their invariants
// and every kernel its results.
TEST(BvhStructure, BigLeavesFlatAndFarGeometryMatchBruteForce) {
  BvhOptions big_leaves;
  big_leaves.max_leaf_size = 600;
  big_leaves.traversal_cost = 1000.0f;  // one leaf per subtree up to 600 triangles
  const Mesh soup = test::make_soup(3000, 41);
  for (const BvhKernel kernel : test_kernels()) {
    BvhOptions o = big_leaves;
    o.kernel = kernel;
    const Bvh bvh = Bvh::build(soup.input(), o);
    check_invariants(bvh, soup.input(), o);
    uint32_t largest = 0;
    for (const BvhNode& nd : bvh.nodes()) largest = std::max(largest, nd.count);
    EXPECT_GT(largest, 255u) << "the test needs leaves of hundreds of triangles";
  }
  expect_matches_brute(soup.input(), test::make_oracle_rays(soup.bounds(), soup.positions, 6000, 42), "big leaves",
                       big_leaves);
  // A flat grid far from the origin (child boxes flat in y), and the same grid scaled tiny.
  for (const float s : {1.0f, 1e-6f}) {
    Mesh grid = test::make_grid(40, 0.5f * s, 1e5f * s, -3e5f * s, 7.0f * s);
    for (const BvhKernel kernel : test_kernels()) {
      BvhOptions o;
      o.kernel = kernel;
      check_invariants(Bvh::build(grid.input(), o), grid.input(), o);
    }
    expect_matches_brute(grid.input(), test::make_oracle_rays(grid.bounds(), grid.positions, 6000, 43),
                         "far flat grid " + std::to_string(s));
  }
}

// ---------------------------------------------------------------------------------------------
// Degenerate triangles and overflowing costs. The build's reference pass decides in SSE2 which
// triangles are degenerate (no surface: they get no reference, so no structure can report a
// hit on them). It is documented to compute exactly the floats of accel::is_degenerate, the
// predicate the brute-force twin and the hit normal use; these tests compare the two directly,
// on triangles at the edges of that predicate, through both code paths of the pass (the serial
// one that compacts as it goes, and the parallel one that flags and compacts afterwards).

/// Triangles whose squared cross product lies near 0, near the smallest subnormal, near the
/// overflow to infinity, or is exactly zero (collinear, coincident vertices), at magnitudes
/// from 2^-70 to 2^60, plus ordinary ones; each vertex has its own three floats.
Mesh edge_of_degeneracy_soup(int count, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> unit(-1.0f, 1.0f);
  std::uniform_int_distribution<int> kind(0, 6), exponent(-70, 60);
  Mesh m;
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
    const Mesh m = edge_of_degeneracy_soup(count, 7u + static_cast<uint32_t>(count));
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
  const Mesh m = edge_of_degeneracy_soup(3000, 3007u);
  std::vector<Ray> rays = test::make_oracle_rays(m.bounds(), m.positions, 4000, 11u);
  // The soup is sparse in its huge box (the oracle's mix hits ~4%): also a ray at the centroid
  // of every triangle with a surface, from a random side, so the oracle sees enough hits.
  std::mt19937 rng(12u);
  std::uniform_real_distribution<float> unit(-1.0f, 1.0f);
  for (size_t t = 0; t < m.triangle_count(); ++t) {
    const Vec3 &a = m.positions[m.indices[3 * t]], &b = m.positions[m.indices[3 * t + 1]],
               &c = m.positions[m.indices[3 * t + 2]];
    if (accel::is_degenerate(a, b, c)) continue;
    const Vec3 centroid = (a + b + c) * (1.0f / 3.0f);
    const Vec3 d = normalize(Vec3{unit(rng), unit(rng), unit(rng)});
    const float reach = 4.0f * std::max({length(b - a), length(c - a), length(c - b)});
    rays.push_back(Ray{centroid - d * reach, 0.0f, d, kInf});
  }
  expect_matches_brute(m.input(), rays, "overflowing SAH costs");
  // The high-quality build's reinsertion sums the same infinite areas.
  BvhOptions high;
  high.quality = BvhQuality::High;
  expect_matches_brute(m.input(), rays, "overflowing SAH costs, quality high", high);
}

// ---------------------------------------------------------------------------------------------
// BvhQuality::High: the tree built down to single triangles, improved by subtree reinsertion
// (accel/bvh_optimize.h), leaves chosen by the collapse.

TEST(BvhQuality, NamesParseAndUnknownNamesAreRefused) {
  EXPECT_EQ(parse_bvh_quality("fast"), BvhQuality::Fast);
  EXPECT_EQ(parse_bvh_quality("high"), BvhQuality::High);
  for (const BvhQuality q : {BvhQuality::Fast, BvhQuality::High}) EXPECT_EQ(parse_bvh_quality(bvh_quality_name(q)), q);
  try {
    parse_bvh_quality("best");
    FAIL() << "unknown quality accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("fast, high"), std::string::npos) << e.what();
  }
  EXPECT_EQ(BvhOptions{}.quality, BvhQuality::Fast);
}

TEST(BvhQuality, HighQualityTreesMatchBruteForce) {
  BvhOptions high;
  high.quality = BvhQuality::High;
  const Mesh sphere = test::make_sphere(24, 48, 1.5f, {0.2f, -0.1f, 0.3f});
  expect_matches_brute(sphere.input(), test::make_oracle_rays(sphere.bounds(), sphere.positions, 20000, 31), "sphere high", high);
  const Mesh grid = test::make_grid(32, 0.25f, -4.0f, -4.0f, 0.5f);
  expect_matches_brute(grid.input(), test::make_oracle_rays(grid.bounds(), grid.positions, 20000, 32), "grid high", high);
  const Mesh soup = test::make_soup(3000, 3);
  high.packets = false;
  expect_matches_brute(soup.input(), test::make_oracle_rays(soup.bounds(), soup.positions, 20000, 33), "soup high", high);
  high.max_leaf_size = 1;
  high.threads = 1;
  expect_matches_brute(soup.input(), test::make_oracle_rays(soup.bounds(), soup.positions, 5000, 34), "soup high leaf 1", high);
}

TEST(BvhQuality, HighQualityKeepsInvariantsLowersCostAndIsDeterministic) {
  const Mesh soup = test::make_soup(40000, 5);  // above the task threshold: the build runs tasks
  const Mesh sphere = test::make_sphere(40, 80);
  for (const BvhKernel kernel : test_kernels()) {
    BvhOptions o;
    o.kernel = kernel;
    o.quality = BvhQuality::High;
    const Bvh bvh = Bvh::build(sphere.input(), o);
    check_invariants(bvh, sphere.input(), o);
  }
  BvhOptions one, two;
  one.quality = two.quality = BvhQuality::High;
  one.threads = 1;
  two.threads = 2;
  const Bvh a = Bvh::build(soup.input(), one), b = Bvh::build(soup.input(), two);
  check_invariants(a, soup.input(), one);
  const BuildInfo& info = a.build_info();
  // Every leaf of the binary tree is one triangle; reinsertion moved subtrees and lowered the
  // binary tree's cost below the one it was built with.
  EXPECT_EQ(info.leaves, a.prim_ids().size());
  EXPECT_GT(a.prim_ids().size(), soup.triangle_count() / 2);
  EXPECT_GT(info.reinsertions, 0u);
  EXPECT_GT(info.optimize_ms, 0.0);
  EXPECT_LT(info.sah_cost, info.sah_cost_binned);
  EXPECT_GT(info.sah_cost, 0.5 * info.sah_cost_binned);
  // Same tree and traversal layout for any thread count (the optimisation is serial).
  EXPECT_TRUE(std::equal(a.prim_ids().begin(), a.prim_ids().end(), b.prim_ids().begin(), b.prim_ids().end()));
  ASSERT_EQ(a.nodes().size(), b.nodes().size());
  for (size_t i = 0; i < a.nodes().size(); ++i) {
    const BvhNode &x = a.nodes()[i], &y = b.nodes()[i];
    ASSERT_TRUE(x.min == y.min && x.max == y.max && x.left_first == y.left_first && x.count == y.count) << "node " << i;
  }
  EXPECT_EQ(info.sah_cost, b.build_info().sah_cost);
  const auto same_bytes = [](auto x, auto y) {
    return x.size() == y.size() && (x.empty() || std::memcmp(x.data(), y.data(), x.size_bytes()) == 0);
  };
  EXPECT_TRUE(same_bytes(a.triangle_blocks(), b.triangle_blocks()));
  // Fast builds report no optimisation.
  const BuildInfo fast = Bvh::build(soup.input()).build_info();
  EXPECT_EQ(fast.reinsertions, 0u);
  EXPECT_EQ(fast.optimize_ms, 0.0);
  EXPECT_EQ(fast.sah_cost_binned, 0.0);
}

/// A binary tree in the builder's layout over unit boxes [i, i + 1] x [0, 1] x [0, 1] along x,
/// one leaf each: leaves[k] is the box index of the k-th leaf in depth-first order, paired as
/// ((l0 l1)(l2 l3))((l4 l5)(l6 l7)).
std::vector<BvhNode> eight_leaf_tree(const uint32_t (&leaves)[8], std::vector<uint32_t>& prim_ids) {
  std::vector<BvhNode> n(16);
  const auto leaf = [&](uint32_t node, uint32_t k) {
    const float x = static_cast<float>(leaves[k]);
    n[node].min = {x, 0, 0};
    n[node].max = {x + 1, 1, 1};
    n[node].left_first = k;
    n[node].count = 1;
  };
  // Root 0 -> (2, 3); 2 -> (4, 5); 3 -> (6, 7); 4..7 -> leaf pairs at 8..15.
  const uint32_t kids[8][2] = {{2, 3}, {0, 0}, {4, 5}, {6, 7}, {8, 9}, {10, 11}, {12, 13}, {14, 15}};
  for (uint32_t k = 0; k < 8; ++k) leaf(8 + k, k);
  for (uint32_t j = 7; j != ~0u; --j) {
    if (j == 1) continue;
    const BvhNode &l = n[kids[j][0]], &r = n[kids[j][1]];
    n[j].min = min(l.min, r.min);
    n[j].max = max(l.max, r.max);
    n[j].left_first = kids[j][0];
    n[j].count = 0;
  }
  prim_ids.resize(8);
  for (uint32_t k = 0; k < 8; ++k) prim_ids[k] = leaves[k];
  return n;
}

/// Checks the builder's layout (node 0 the root, even sibling pairs after their parent, boxes
/// the exact unions of their children, every subtree's triangles contiguous) and returns the
/// sum of the interior nodes' half areas.
double check_layout(const std::vector<BvhNode>& n, const std::vector<uint32_t>& ids, uint32_t& depth_out) {
  double cost = 0.0;
  uint32_t next_prim = 0;
  depth_out = 0;
  // (node, depth); depth-first, left first: leaves must come in prim order.
  std::vector<std::pair<uint32_t, uint32_t>> stack{{0u, 0u}};
  while (!stack.empty()) {
    const auto [j, d] = stack.back();
    stack.pop_back();
    depth_out = std::max(depth_out, d);
    const BvhNode& nd = n[j];
    if (nd.is_leaf()) {
      EXPECT_EQ(nd.left_first, next_prim) << "leaf " << j << " out of depth-first order";
      next_prim += nd.count;
      continue;
    }
    EXPECT_GT(nd.left_first, j);
    EXPECT_EQ(nd.left_first % 2, 0u);
    const BvhNode &l = n[nd.left_first], &r = n[nd.left_first + 1];
    EXPECT_TRUE(nd.min == min(l.min, r.min) && nd.max == max(l.max, r.max)) << "node " << j << " is not its children's union";
    const Vec3 e = nd.max - nd.min;
    cost += double{e.x} * e.y + double{e.y} * e.z + double{e.z} * e.x;
    stack.push_back({nd.left_first + 1, d + 1});
    stack.push_back({nd.left_first, d + 1});
  }
  EXPECT_EQ(next_prim, ids.size());
  std::vector<uint32_t> sorted = ids;
  std::sort(sorted.begin(), sorted.end());
  for (uint32_t i = 0; i < sorted.size(); ++i) EXPECT_EQ(sorted[i], i) << "prim ids are not a permutation";
  return cost;
}

TEST(BvhQuality, ReinsertionRepairsABadlyPairedTree) {
  // Boxes paired far apart: (0 7)(1 6) | (2 5)(3 4). Interior half areas (2 L + 1 for length L):
  // pairs 17 + 13 + 9 + 5, their parents 17 + 9, the root 17: 87. The best tree pairs
  // neighbours, ((0 1)(2 3))((4 5)(6 7)): 4 x 5 + 2 x 9 + 17 = 55.
  std::vector<uint32_t> ids;
  std::vector<BvhNode> n = eight_leaf_tree({0, 7, 1, 6, 2, 5, 3, 4}, ids);
  uint32_t depth = 0;
  ASSERT_DOUBLE_EQ(check_layout(n, ids, depth), 87.0);
  const accel::ReinsertionStats st = accel::optimize_by_reinsertion(n, ids, 96);
  EXPECT_DOUBLE_EQ(st.cost_before, 87.0);
  EXPECT_GT(st.moves, 0u);
  const double after = check_layout(n, ids, depth);
  EXPECT_DOUBLE_EQ(after, st.cost_after);
  EXPECT_DOUBLE_EQ(after, 55.0) << "reinsertion did not find the neighbour pairing";
  EXPECT_LE(depth, 4u);
  // Each box keeps its own leaf: the leaf at prim slot k still holds box ids[k].
  for (const BvhNode& nd : n)
    if (nd.is_leaf()) {
      EXPECT_EQ(nd.min.x, static_cast<float>(ids[nd.left_first]));
    }

  // Already the best tree: nothing gets worse (the old place is always a candidate).
  std::vector<BvhNode> good = eight_leaf_tree({0, 1, 2, 3, 4, 5, 6, 7}, ids);
  const accel::ReinsertionStats keep = accel::optimize_by_reinsertion(good, ids, 96);
  EXPECT_DOUBLE_EQ(keep.cost_after, 55.0);
  EXPECT_DOUBLE_EQ(check_layout(good, ids, depth), 55.0);

  // The depth bound holds: with max depth 3 (what the tree has), no move may make it deeper.
  n = eight_leaf_tree({0, 7, 1, 6, 2, 5, 3, 4}, ids);
  accel::optimize_by_reinsertion(n, ids, 3);
  check_layout(n, ids, depth);
  EXPECT_LE(depth, 3u);
}

TEST(BvhQuality, HighQualityOnBunnyLowersCostAndMatchesBruteForce) {
  SPECULA_REQUIRE_MESH(path, "stanford-bunny.obj");
  const Scene scene = load_obj(path);
  const TriangleInput input{scene.positions, scene.indices, {}};
  BvhOptions o;
  o.quality = BvhQuality::High;
  const Bvh bvh = Bvh::build(input, o);
  check_invariants(bvh, input, o);
  EXPECT_LT(bvh.build_info().sah_cost, bvh.build_info().sah_cost_binned);
  // The binary tree of single triangles costs less than the fast build's (36.28, leaves of up
  // to 8 triangles), as a binary SAH tree.
  EXPECT_LT(bvh.build_info().sah_cost, Bvh::build(input).build_info().sah_cost);
  expect_matches_brute(input, test::make_oracle_rays(scene.bounds(), scene.positions, 20000, 777), "bunny high", o);
}

}  // namespace
}  // namespace specula
