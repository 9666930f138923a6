/// \file voxel_brute.h
/// The ray/voxel kernel shared by every voxel tracer, and the brute-force voxel tracer built
/// on it (the oracle of the octree and grid tests). Internal header (owner: voxel tracers).
///
/// All tracers map a ray once into the grid's local frame (LocalRay) and decide hits with
/// cell_span / hit_cell below; their traversals compute node and cell boundaries with the
/// same formula, (integer plane - o) * inv, so every number a traversal compares equals the
/// one the kernel computes. That is what makes the octree, the grid and the brute force agree
/// bit for bit (see the semantics in include/specula/voxel_tracer.h).
#pragma once

#include <immintrin.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "specula/ray.h"
#include "specula/voxel.h"
#include "specula/voxel_tracer.h"

namespace specula::voxel {

/// A ray in the local frame of a grid (voxel (x, y, z) = [x, x+1]^3 ...).
struct LocalRay {
  float o[3];
  float d[3];    ///< 0 on fixed axes
  float inv[3];  ///< 1 / d; 0 on fixed axes
  float tmin, tmax;
  float scale;      ///< local units per world unit (to convert contour offsets)
  uint32_t mirror;  ///< bit i: the ray moves towards -i
  uint32_t fixed;   ///< bit i: the ray does not move along i (d == +-0 or 1/d not finite)
};

/// Maps \p ray into \p g's local frame. False for rays that miss everything by definition:
/// non-finite origin or direction, NaN or reversed [tmin, tmax], zero direction.
inline bool make_local_ray(const Ray& ray, const VoxelGrid& g, LocalRay& r) {
  if (!is_finite(ray.org) || !is_finite(ray.dir) || std::isnan(ray.tmin) || std::isnan(ray.tmax) ||
      !(ray.tmin <= ray.tmax))
    return false;
  const float scale = static_cast<float>(g.resolution()) / g.side;
  r.scale = scale;
  r.tmin = ray.tmin;
  r.tmax = ray.tmax;
  r.mirror = 0;
  r.fixed = 0;
  for (int i = 0; i < 3; ++i) {
    const float o = (ray.org[i] - g.origin[i]) * scale;
    const float d = ray.dir[i] * scale;
    if (!std::isfinite(o) || !std::isfinite(d)) return false;
    const float inv = 1.0f / d;
    r.o[i] = o;
    if (d == 0.0f || !std::isfinite(inv)) {
      r.fixed |= 1u << i;
      r.d[i] = 0.0f;
      r.inv[i] = 0.0f;
    } else {
      r.d[i] = d;
      r.inv[i] = inv;
      if (d < 0.0f) r.mirror |= 1u << i;
    }
  }
  return r.fixed != 7u;
}

/// What make_local_ray needs of a grid, computed once per batch.
struct LocalFrame {
  float origin[3];
  float scale;  ///< resolution / side, as make_local_ray computes it

  explicit LocalFrame(const VoxelGrid& g)
      : origin{g.origin.x, g.origin.y, g.origin.z}, scale(static_cast<float>(g.resolution()) / g.side) {}
};

/// make_local_ray for batches, in SSE (the x86-64 baseline): the same checks (tmin <= tmax is
/// false for NaN, and the finiteness of the local origin and direction implies that of the
/// world ones) and bit for bit the same LocalRay, since SSE arithmetic is IEEE single
/// precision like the scalar code.
inline bool make_local_ray(const Ray& ray, const LocalFrame& f, LocalRay& r) {
  static_assert(offsetof(Ray, tmin) == 12 && offsetof(Ray, dir) == 16 && offsetof(Ray, tmax) == 28);
  static_assert(offsetof(LocalRay, d) == 12 && offsetof(LocalRay, inv) == 24 && offsetof(LocalRay, tmin) == 36);
  if (!(ray.tmin <= ray.tmax)) return false;
  const __m128 max_finite = _mm_set1_ps(3.40282347e38f);
  const __m128 abs_mask = _mm_castsi128_ps(_mm_set1_epi32(0x7FFFFFFF));
  const __m128 scale = _mm_set1_ps(f.scale);
  const __m128 o = _mm_mul_ps(_mm_sub_ps(_mm_loadu_ps(&ray.org.x), _mm_setr_ps(f.origin[0], f.origin[1], f.origin[2], 0.0f)), scale);
  const __m128 d = _mm_mul_ps(_mm_loadu_ps(&ray.dir.x), scale);
  const int finite = _mm_movemask_ps(_mm_and_ps(_mm_cmple_ps(_mm_and_ps(o, abs_mask), max_finite),
                                                _mm_cmple_ps(_mm_and_ps(d, abs_mask), max_finite)));
  if ((finite & 7) != 7) return false;
  const __m128 inv = _mm_div_ps(_mm_set1_ps(1.0f), d);
  const __m128 fix = _mm_or_ps(_mm_cmpeq_ps(d, _mm_setzero_ps()),
                               _mm_cmpnle_ps(_mm_and_ps(inv, abs_mask), max_finite));  // also NaN
  const uint32_t fixed = static_cast<uint32_t>(_mm_movemask_ps(fix)) & 7u;
  const uint32_t mirror = static_cast<uint32_t>(_mm_movemask_ps(_mm_cmplt_ps(d, _mm_setzero_ps()))) & ~fixed & 7u;
  // Overlapping 4-lane stores, in field order: each one's fourth lane is overwritten next.
  _mm_storeu_ps(r.o, o);
  _mm_storeu_ps(r.d, _mm_andnot_ps(fix, d));
  _mm_storeu_ps(r.inv, _mm_andnot_ps(fix, inv));
  r.tmin = ray.tmin;
  r.tmax = ray.tmax;
  r.scale = f.scale;
  r.mirror = mirror;
  r.fixed = fixed;
  return fixed != 7u;
}

/// The same ray in the frame of the grid \p k levels coarser (coordinates / 2^k). Exact (power
/// of two scaling), so it equals make_local_ray on the coarser grid.
inline LocalRay coarsen(const LocalRay& r, int k) {
  LocalRay c = r;
  for (int i = 0; i < 3; ++i) {
    c.o[i] = std::ldexp(r.o[i], -k);
    c.d[i] = std::ldexp(r.d[i], -k);
    c.inv[i] = std::ldexp(r.inv[i], k);
  }
  c.scale = std::ldexp(r.scale, -k);
  return c;
}

/// The crossing of one cell: [te, tx], entered through the face normal to \p axis (-1: the
/// ray starts inside, te == tmin).
struct CellSpan {
  float te, tx;
  int axis;
};

/// Parameter interval of cell \p c (local integer coordinates); true when it has positive
/// length.
inline bool cell_span(const LocalRay& r, const uint32_t c[3], CellSpan& s) {
  float tplane = -kInf, tx = r.tmax;
  int axis = -1;
  for (int i = 0; i < 3; ++i) {
    const float lo = static_cast<float>(c[i]);
    const float hi = static_cast<float>(c[i] + 1u);
    if ((r.fixed >> i) & 1u) {
      if (!(lo <= r.o[i] && r.o[i] < hi)) return false;
      continue;
    }
    const bool neg = (r.mirror >> i) & 1u;
    const float t0 = ((neg ? hi : lo) - r.o[i]) * r.inv[i];
    const float t1 = ((neg ? lo : hi) - r.o[i]) * r.inv[i];
    if (t0 > tplane) {
      tplane = t0;
      axis = i;
    }
    tx = std::min(tx, t1);
  }
  if (tplane >= r.tmin) {
    s.te = tplane;
    s.axis = axis;
  } else {
    s.te = r.tmin;
    s.axis = -1;
  }
  s.tx = tx;
  return s.te < s.tx;
}

/// Outward normal of the face normal to \p axis through which the ray enters (against the ray).
inline Vec3 face_normal(const LocalRay& r, int axis) {
  // Per component by selects, not Vec3::operator[] (a chain of branches on the axis, which
  // varies from pixel to pixel: mispredicted).
  const float s = ((r.mirror >> axis) & 1u) ? 1.0f : -1.0f;
  return Vec3{axis == 0 ? s : 0.0f, axis == 1 ? s : 0.0f, axis == 2 ? s : 0.0f};
}

/// Normal for a ray starting inside a voxel: -sign(d_k) e_k, k = axis of the largest |d|.
inline Vec3 inside_normal(const LocalRay& r) {
  int k = 0;
  for (int i = 1; i < 3; ++i)
    if (std::fabs(r.d[i]) > std::fabs(r.d[k])) k = i;
  return face_normal(r, k);
}

struct CellHit {
  float t;
  Vec3 n;
};

/// hit_cell for a cell the ray crosses, given its crossing \p s: te and axis exactly as
/// cell_span gives them, tx equal in value (it is only compared). The octree's packets compute
/// the span of every lane with vector operations and call this directly.
inline bool hit_span(const LocalRay& r, const uint32_t c[3], const VoxelAttributes& a, VoxelHitMode mode,
                     const CellSpan& s, CellHit& h) {
  if (mode == VoxelHitMode::Cubes) {
    h.t = s.te;
    h.n = s.axis >= 0 ? face_normal(r, s.axis) : inside_normal(r);
    return true;
  }
  const float cx = static_cast<float>(c[0]) + 0.5f, cy = static_cast<float>(c[1]) + 0.5f,
              cz = static_cast<float>(c[2]) + 0.5f;
  const Vec3& n = a.normal;
  const float no = n.x * (r.o[0] - cx) + n.y * (r.o[1] - cy) + n.z * (r.o[2] - cz);
  const float nd = n.x * r.d[0] + n.y * r.d[1] + n.z * r.d[2];
  const float klo = a.contour_lo * r.scale, khi = a.contour_hi * r.scale;
  float s0, s1;
  if (nd == 0.0f) {
    if (!(klo <= no && no <= khi)) return false;
    s0 = -kInf;
    s1 = kInf;
  } else {
    // One division for both planes (the octree's packets divide vectors of 16 lanes here,
    // whose latency and throughput are those of a dozen multiplications).
    const float inv_nd = 1.0f / nd;
    const float ta = (klo - no) * inv_nd, tb = (khi - no) * inv_nd;
    s0 = std::min(ta, tb);
    s1 = std::max(ta, tb);
  }
  const float t = std::max(s.te, s0);
  if (!(t <= s1 && t < s.tx)) return false;
  h.t = t;
  h.n = a.normal;
  return true;
}

/// What a traversal already computed of a ray crossing a cell: the span, and in contour mode
/// possibly hit_span's answer itself (contour >= 0: 1 = hit at t, 0 = miss).
struct CellCrossing {
  CellSpan span;
  int contour = -1;
  float t = 0.0f;
};

/// hit_span from a CellCrossing (the octree's packets compute the contour test of all lanes
/// at once, with the operations of hit_span in the same order).
inline bool hit_crossing(const LocalRay& r, const uint32_t c[3], const VoxelAttributes& a, VoxelHitMode mode,
                         const CellCrossing& x, CellHit& h) {
  if (mode == VoxelHitMode::Contours && x.contour >= 0) {
    if (x.contour == 0) return false;
    h.t = x.t;
    h.n = a.normal;
    return true;
  }
  return hit_span(r, c, a, mode, x.span, h);
}

/// Ray against occupied cell \p c with attributes \p a in \p mode (semantics: voxel_tracer.h).
inline bool hit_cell(const LocalRay& r, const uint32_t c[3], const VoxelAttributes& a, VoxelHitMode mode,
                     CellHit& h) {
  CellSpan s;
  return cell_span(r, c, s) && hit_span(r, c, a, mode, s, h);
}

/// The octree's packet kernel on this CPU: lanes per packet (32 with AVX-512, 16 with AVX2, 1 =
/// single rays only) and whether it uses AVX-512; within the limits of
/// set_svo_packet_width_limit (tests use it to run every kernel: the widest of 32, 16, 8 and 1
/// within \p width, AVX-512 ones only when \p avx512).
struct SvoPacketKernel {
  int width;
  bool avx512;
};
SvoPacketKernel svo_packet_kernel();
void set_svo_packet_width_limit(int width, bool avx512 = true);

/// Throws specula::Error unless \p set is valid for a tracer (see build_voxel_tracer).
void validate_set(const VoxelSet& set, const char* who);

/// The set's attributes, or defaults for an occupancy-only set (normal +z, contour slab
/// covering the whole cube so contour mode hits the cubes).
std::vector<VoxelAttributes> attributes_or_default(const VoxelSet& set);

/// Brute force over the voxel list: every voxel tested for every ray, the smallest hit t kept
/// (ties cannot occur, see voxel_tracer.h; the first in set order would win).
class VoxelBruteTracer final : public VoxelTracer {
 public:
  explicit VoxelBruteTracer(const VoxelSet& set, const VoxelTracerOptions& options = {});

  std::string name() const override { return "voxel_brute"; }
  void intersect_skipping(std::span<const Ray> rays, std::span<const uint32_t> skip_material, std::span<Hit> hits,
                          TraceStats* stats = nullptr,
                          std::span<const uint32_t> skip_prim = {}) const override;
  void transmittance(std::span<const Ray> rays, std::span<Vec3> out, TraceStats* stats = nullptr) const override;
  size_t memory_bytes() const override;

  const VoxelAttributes& attributes(uint32_t prim) const override;
  const VoxelGrid& grid() const override { return grid_; }
  size_t voxel_count() const override { return cells_.size(); }
  VoxelHitMode hit_mode() const override { return mode_; }
  void set_hit_mode(VoxelHitMode mode) override { mode_ = mode; }

 private:
  struct Cell {
    uint32_t c[3];
  };
  VoxelGrid grid_;
  std::vector<Cell> cells_;
  std::vector<VoxelAttributes> attrs_;
  VoxelHitMode mode_;
};

}  // namespace specula::voxel
