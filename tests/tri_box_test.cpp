// Exact triangle / box tests (src/voxel/tri_box.h) against an independent exact reference.
//
// The reference decides T ∩ B ≠ ∅ as feasibility of a 2D linear system in barycentric
// coordinates (b, c): p = v0 + b (v1 - v0) + c (v2 - v0) with b >= 0, c >= 0, b + c <= 1 and
// lo <= p <= hi (closed). The feasible set is a compact convex polygon in (b, c), so when it is
// non-empty it has a vertex, where two linearly independent constraints are tight. The
// reference enumerates every such pair, solves it by Cramer's rule and checks all constraints,
// all in exact __int128 arithmetic (no division, no rounding). It shares nothing with the
// separating-axis formulation under test.
#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <vector>

#include "tri_box_reference.h"
#include "voxel/tri_box.h"

namespace {

using specula::voxel::LatticeBox;
using specula::voxel::TriBox;
using specula::test::reference_overlap;

TriBox make(const int64_t v[3][3]) {
  TriBox t;
  specula::voxel::prepare(t, v[0], v[1], v[2]);
  return t;
}

std::string describe(const int64_t v[3][3], const LatticeBox& b) {
  std::string s = "triangle";
  for (int i = 0; i < 3; ++i)
    s += " (" + std::to_string(v[i][0]) + "," + std::to_string(v[i][1]) + "," + std::to_string(v[i][2]) + ")";
  s += " box lo (" + std::to_string(b.lo[0]) + "," + std::to_string(b.lo[1]) + "," + std::to_string(b.lo[2]) +
       ") size " + std::to_string(b.size);
  return s;
}

/// Checks the SAT against the reference and the relations between the partial tests.
void check_one(const int64_t v[3][3], const LatticeBox& b, int* overlaps = nullptr) {
  const TriBox t = make(v);
  const bool ref = reference_overlap(v, b);
  const bool sat = specula::voxel::sat_overlap(t, b);
  ASSERT_EQ(sat, ref) << describe(v, b);
  if (sat) {
    EXPECT_TRUE(specula::voxel::aabb_overlap(t, b)) << describe(v, b);
    EXPECT_TRUE(specula::voxel::plane_overlap(t, b)) << describe(v, b);
    if (overlaps) ++*overlaps;
  }
  if (specula::voxel::vertex_inside(t, b)) {
    EXPECT_TRUE(ref) << describe(v, b);
  }
}

TEST(TriBoxReference, KnownCases) {
  const LatticeBox b{{0, 0, 0}, 4};
  const int64_t inside[3][3] = {{1, 1, 1}, {2, 1, 1}, {1, 2, 1}};
  const int64_t far[3][3] = {{10, 10, 10}, {11, 10, 10}, {10, 11, 10}};
  const int64_t touch_corner[3][3] = {{4, 4, 4}, {8, 4, 4}, {4, 8, 4}};
  const int64_t near_corner[3][3] = {{5, 4, 4}, {8, 4, 4}, {4, 8, 4}};  // edge (5,4)-(4,8) passes outside
  // Diagonal plane x + y + z = 13 misses the box (max sum 12); its bounding box overlaps.
  const int64_t diag_miss[3][3] = {{13, 0, 0}, {0, 13, 0}, {0, 0, 13}};
  const int64_t diag_hit[3][3] = {{12, 0, 0}, {0, 12, 0}, {0, 0, 12}};  // touches corner (4,4,4)
  EXPECT_TRUE(reference_overlap(inside, b));
  EXPECT_FALSE(reference_overlap(far, b));
  EXPECT_TRUE(reference_overlap(touch_corner, b));
  EXPECT_FALSE(reference_overlap(near_corner, b));
  EXPECT_FALSE(reference_overlap(diag_miss, b));
  EXPECT_TRUE(reference_overlap(diag_hit, b));
  for (auto* v : {inside, far, touch_corner, near_corner, diag_miss, diag_hit}) check_one(v, b);
  const int64_t beside[3][3] = {{5, 0, 2}, {9, 0, 2}, {5, 4, 2}};       // x >= 5: bounding boxes apart
  const int64_t beside_diag[3][3] = {{6, 0, 0}, {0, 6, 0}, {6, 6, 0}};  // x + y >= 6 holds (4, 4, 0)
  EXPECT_FALSE(reference_overlap(beside, b));
  EXPECT_TRUE(reference_overlap(beside_diag, b));
  check_one(beside, b);
  check_one(beside_diag, b);
  // In the box's face plane z = 0, beside the box: bounding box and plane overlap, x + y >= 9 > 8
  // does not; only the edge axes separate it.
  const int64_t in_plane_miss[3][3] = {{3, 6, 0}, {6, 3, 0}, {6, 6, 0}};
  EXPECT_FALSE(reference_overlap(in_plane_miss, b));
  check_one(in_plane_miss, b);
  const TriBox t = make(in_plane_miss);
  EXPECT_TRUE(specula::voxel::aabb_overlap(t, b));
  EXPECT_TRUE(specula::voxel::plane_overlap(t, b));
  EXPECT_FALSE(specula::voxel::edge_overlap(t, b));  // only the edge axes separate it
}

TEST(TriBox, RandomSmallCoordinatesManyTouches) {
  // Coordinates in [0, 12] around a box [4, 8]^3: a large share of the cases touch faces,
  // edges or corners exactly; about a third of the triangles are degenerate or axis-aligned.
  std::mt19937_64 rng(12345);
  std::uniform_int_distribution<int64_t> coord(0, 12), kind(0, 9), tpar(-2, 3);
  const LatticeBox b{{4, 4, 4}, 4};
  int overlaps = 0;
  for (int iter = 0; iter < 200000; ++iter) {
    int64_t v[3][3];
    for (auto& p : v)
      for (auto& c : p) c = coord(rng);
    switch (kind(rng)) {
      case 0:  // point
        for (int k = 0; k < 3; ++k) v[1][k] = v[2][k] = v[0][k];
        break;
      case 1:  // two equal vertices
        for (int k = 0; k < 3; ++k) v[2][k] = v[1][k];
        break;
      case 2: {  // collinear: v2 = v0 + t (v1 - v0), kept in range
        const int64_t t = tpar(rng);
        for (int k = 0; k < 3; ++k) v[2][k] = std::clamp<int64_t>(v[0][k] + t * (v[1][k] - v[0][k]), 0, 12);
        break;
      }
      case 3: {  // axis-aligned, often on a box face
        const int axis = static_cast<int>(coord(rng) % 3);
        const int64_t c = (coord(rng) % 2) ? 4 + 4 * (coord(rng) % 2) : coord(rng);
        for (auto& p : v) p[axis] = c;
        break;
      }
      default:
        break;
    }
    check_one(v, b, &overlaps);
    if (::testing::Test::HasFatalFailure()) return;
  }
  // Both outcomes are well represented.
  EXPECT_GT(overlaps, 20000);
  EXPECT_LT(overlaps, 180000);
}

TEST(TriBox, RandomFullLatticeRangeAndSlivers) {
  // Full 29-bit coordinates (no overflow anywhere), boxes of every level, and slivers: thin
  // triangles whose third vertex is a tiny offset from an edge.
  std::mt19937_64 rng(777);
  const int64_t side = specula::voxel::kLatticeSide;
  std::uniform_int_distribution<int64_t> coord(0, side), small(-3, 3), level(0, 21);
  for (int iter = 0; iter < 100000; ++iter) {
    const int L = static_cast<int>(level(rng));
    const int64_t size = side >> L;
    LatticeBox b{{0, 0, 0}, size};
    for (auto& c : b.lo) c = (coord(rng) >> (specula::voxel::kLatticeBits - L)) * size;
    for (auto& c : b.lo) c = std::min(c, side - size);
    int64_t v[3][3];
    // Vertices near the box: within a few box sizes (clamped to the lattice).
    std::uniform_int_distribution<int64_t> near(-2 * size, 3 * size);
    for (auto& p : v)
      for (int k = 0; k < 3; ++k) p[k] = std::clamp<int64_t>(b.lo[k] + near(rng), 0, side);
    if (iter % 3 == 0)  // sliver
      for (int k = 0; k < 3; ++k)
        v[2][k] = std::clamp<int64_t>((v[0][k] + v[1][k]) / 2 + small(rng), 0, side);
    check_one(v, b);
    if (::testing::Test::HasFatalFailure()) return;
  }
}

TEST(TriBox, MonotoneDownTheOctree) {
  // A triangle that overlaps a child overlaps its parent: the property that makes level-by-level
  // testing give exactly the leaf-level set.
  std::mt19937_64 rng(99);
  std::uniform_int_distribution<int64_t> coord(0, 64);
  for (int iter = 0; iter < 20000; ++iter) {
    int64_t v[3][3];
    for (auto& p : v)
      for (auto& c : p) c = coord(rng);
    const TriBox t = make(v);
    for (int64_t x = 0; x < 64; x += 16)
      for (int64_t y = 0; y < 64; y += 16)
        for (int64_t z = 0; z < 64; z += 16) {
          const LatticeBox parent{{x, y, z}, 16};
          const bool p = specula::voxel::sat_overlap(t, parent);
          bool any_child = false;
          for (int c = 0; c < 8; ++c) {
            const LatticeBox child{{x + (c & 1) * 8, y + (c >> 1 & 1) * 8, z + (c >> 2 & 1) * 8}, 8};
            any_child = any_child || specula::voxel::sat_overlap(t, child);
          }
          ASSERT_EQ(p, any_child) << describe(v, parent);
        }
  }
}

}  // namespace
