/// \file tri_box.h
/// Exact triangle / axis-aligned box overlap tests on an integer lattice, shared by the
/// voxelizer and anything else that needs to know whether a triangle really touches a cube
/// (sparse voxel octree builders, tests).
///
/// Coordinates are integers in [0, 2^kLatticeBits]: the voxelizer maps the root cube of the
/// voxel grid onto that range (every voxel boundary at every depth <= kMaxVoxelDepth is then an
/// integer) and snaps each vertex to the nearest lattice point, 2^-30 of the root side away at
/// most, well below a float's resolution at the scene's scale. On the snapped triangle every
/// test below is computed without rounding (int64, and __int128 for the plane), so:
///   - boxes are closed: a triangle that only touches a face, an edge or a corner overlaps;
///   - the tests are monotone: a triangle that overlaps a box overlaps every box containing
///     it, so applying them level by level down an octree gives exactly the leaf-level answer;
///   - degenerate triangles (collinear, two equal vertices, a point) are handled exactly too.
///
/// The tests are those of seed 000 and of Akenine-Moller's separating-axis theorem (SAT,
/// "Fast 3D Triangle-Box Overlap Testing", 2001), which needs 13 axes: the 3 box normals
/// (= overlap of the triangle's bounding box, `aabb_overlap`), the triangle's normal
/// (`plane_overlap`, seed 000's cube-plane test) and the 9 cross products of triangle edges
/// and box edges (`edge_overlap`). The 9 edge axes are evaluated as in Schwarz and Seidel 2010
/// ("Fast parallel surface and solid voxelization on GPUs"): the triangle is projected onto
/// the three coordinate planes and each 2D edge function is tested at the box's "critical"
/// corner, one comparison per axis, with constants precomputed per triangle.
#pragma once

#include <cstdint>

namespace specula::voxel {

/// Lattice resolution: the root cube spans [0, 2^kLatticeBits] per axis. 29 bits keep every
/// intermediate of the edge tests below 2^62 (int64) and of the plane test below 2^92.
inline constexpr int kLatticeBits = 29;
inline constexpr int64_t kLatticeSide = int64_t{1} << kLatticeBits;

/// An axis-aligned lattice cube [lo, lo + size] per axis (closed).
struct LatticeBox {
  int64_t lo[3];
  int64_t size;
};

/// A triangle prepared for box tests: vertices, bounding box, normal and the 2D edge
/// functions of its three axis projections. Build with `prepare`.
struct TriBox {
  int64_t v[3][3];   ///< vertices, v[vertex][axis], each in [0, kLatticeSide]
  int64_t lo[3];     ///< bounding box minimum
  int64_t hi[3];     ///< bounding box maximum
  int64_t n[3];      ///< normal (e0 x e1, not normalised; zero for a degenerate triangle)
  __int128 d;        ///< plane offset dot(n, v0)
  int64_t nneg;      ///< sum of the negative components of n (plane test critical corner)
  int64_t npos;      ///< sum of the positive components of n
  /// Edge functions per projection p (p = the dropped axis; 2D axes a = p+1, b = p+2 mod 3)
  /// and edge i: f(q) = en[p][i][0] * q_a + en[p][i][1] * q_b + ec[p][i] >= 0 on the
  /// triangle's side of the edge.
  int64_t en[3][3][2];
  int64_t ec[3][3];
  /// Critical-corner offset per projection and edge for a box of side 1:
  /// max(0, en[..][0]) + max(0, en[..][1]); multiply by the box side.
  int64_t ecrit[3][3];
};

/// Fills \p t from three lattice vertices (each coordinate in [0, kLatticeSide]).
inline void prepare(TriBox& t, const int64_t a[3], const int64_t b[3], const int64_t c[3]) {
  for (int k = 0; k < 3; ++k) {
    t.v[0][k] = a[k];
    t.v[1][k] = b[k];
    t.v[2][k] = c[k];
    // Two-operand minima and maxima (selects; the nested conditionals compiled to branches).
    const int64_t ab_lo = a[k] < b[k] ? a[k] : b[k], ab_hi = a[k] > b[k] ? a[k] : b[k];
    t.lo[k] = ab_lo < c[k] ? ab_lo : c[k];
    t.hi[k] = ab_hi > c[k] ? ab_hi : c[k];
  }
  const int64_t e0[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
  const int64_t e1[3] = {c[0] - b[0], c[1] - b[1], c[2] - b[2]};
  t.n[0] = e0[1] * e1[2] - e0[2] * e1[1];
  t.n[1] = e0[2] * e1[0] - e0[0] * e1[2];
  t.n[2] = e0[0] * e1[1] - e0[1] * e1[0];
  t.d = static_cast<__int128>(t.n[0]) * a[0] + static_cast<__int128>(t.n[1]) * a[1] +
        static_cast<__int128>(t.n[2]) * a[2];
  t.nneg = 0;
  t.npos = 0;
  for (int k = 0; k < 3; ++k) (t.n[k] < 0 ? t.nneg : t.npos) += t.n[k];

  for (int p = 0; p < 3; ++p) {
    const int ia = (p + 1) % 3, ib = (p + 2) % 3;
    // n[p] is the signed doubled area of the projection onto (a, b); a degenerate projection
    // (n[p] == 0) takes +1: its three edges then face both ways, which tests the line.
    const int64_t sign = t.n[p] < 0 ? -1 : 1;
    for (int i = 0; i < 3; ++i) {
      const int64_t* v0 = t.v[i];
      const int64_t* v1 = t.v[(i + 1) % 3];
      const int64_t ea = v1[ia] - v0[ia], eb = v1[ib] - v0[ib];
      const int64_t na = -eb * sign, nb = ea * sign;  // inward normal of a counter-clockwise edge
      t.en[p][i][0] = na;
      t.en[p][i][1] = nb;
      t.ec[p][i] = -(na * v0[ia] + nb * v0[ib]);
      t.ecrit[p][i] = (na > 0 ? na : 0) + (nb > 0 ? nb : 0);
    }
  }
}

/// Box normals (3 SAT axes): the triangle's bounding box overlaps the closed box.
inline bool aabb_overlap(const TriBox& t, const LatticeBox& b) {
  for (int k = 0; k < 3; ++k)
    if (t.lo[k] > b.lo[k] + b.size || t.hi[k] < b.lo[k]) return false;
  return true;
}

/// Triangle normal (1 SAT axis, seed 000's plane test): the triangle's plane meets the box,
/// i.e. the box's most negative and most positive corners along n are on opposite sides of
/// the plane or on it. Always true for a degenerate triangle (n = 0).
inline bool plane_overlap(const TriBox& t, const LatticeBox& b) {
  const __int128 c = static_cast<__int128>(t.n[0]) * b.lo[0] + static_cast<__int128>(t.n[1]) * b.lo[1] +
                     static_cast<__int128>(t.n[2]) * b.lo[2] - t.d;
  const __int128 lo = c + static_cast<__int128>(t.nneg) * b.size;
  const __int128 hi = c + static_cast<__int128>(t.npos) * b.size;
  return lo <= 0 && hi >= 0;
}

/// Edge axes (9 SAT axes, as 2D edge functions of the three projections): the projections
/// of box and triangle onto the yz, zx and xy planes overlap (given the bounding boxes do).
inline bool edge_overlap(const TriBox& t, const LatticeBox& b) {
  for (int p = 0; p < 3; ++p) {
    const int ia = (p + 1) % 3, ib = (p + 2) % 3;
    for (int i = 0; i < 3; ++i) {
      const int64_t f = t.en[p][i][0] * b.lo[ia] + t.en[p][i][1] * b.lo[ib] + t.ec[p][i] + t.ecrit[p][i] * b.size;
      if (f < 0) return false;
    }
  }
  return true;
}

/// The full, exact separating-axis test (all 13 axes).
inline bool sat_overlap(const TriBox& t, const LatticeBox& b) {
  return aabb_overlap(t, b) && plane_overlap(t, b) && edge_overlap(t, b);
}

/// Seed 000's shortcut: some vertex of the triangle lies in the closed box (implies overlap).
inline bool vertex_inside(const TriBox& t, const LatticeBox& b) {
  // Bitwise ands of the comparisons as integers: one result from 18 comparisons, without a
  // branch per comparison (&& would branch on each).
  const int64_t hi[3] = {b.lo[0] + b.size, b.lo[1] + b.size, b.lo[2] + b.size};
  int any = 0;
  for (int i = 0; i < 3; ++i) {
    const int64_t* v = t.v[i];
    int in = 1;
    for (int k = 0; k < 3; ++k) in &= static_cast<int>(v[k] >= b.lo[k]) & static_cast<int>(v[k] <= hi[k]);
    any |= in;
  }
  return any != 0;
}

}  // namespace specula::voxel
