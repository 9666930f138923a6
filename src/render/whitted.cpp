// The iterative Whitted integrator (owner: render).
//
// No recursion: every screen tile keeps a wavefront of path segments {ray, pixel, throughput,
// reflection depth, refraction depth, medium stack}. One step traces the whole wavefront with
// one batched Tracer::intersect call, shades every hit (local Blinn-Phong lighting becomes a
// batch of shadow rays, mirror and refraction rays become the next wavefront) and resolves the
// shadow batch with one Tracer::transmittance call. Because throughput is multiplicative,
// each contribution is added straight to its pixel: no backward pass over a ray tree is needed
// (seed 001 stores the tree and walks it backwards because GLSL has no stacks; here the
// weights carry the same information forwards).
//
// Coherence: the tracer gets each wavefront and shadow batch grouped by bounce history (and
// light), see TraceOrder, so a packet tracer finds runs of similar rays; results are scattered
// back, and shading runs in wavefront order as before.
//
// Determinism: a tile is always processed by one thread in the same order, pixels are only
// written by their tile, light samples are keyed by the pixel's global index, and there is no
// shared random state. The film is bit-identical for any thread count.
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <memory>
#include <string>

#include "core/hash.h"
#include "render/bounce.h"
#include "render/exp_lanes.h"
#include "render/fresnel.h"
#include "render/lanes.h"
#include "render/lighting.h"
#include "render/phong.h"
#include "render/sky.h"
#include "specula/error.h"
#include "specula/render.h"
#include "specula/timer.h"
#include "specula/voxel_tracer.h"

namespace specula {

std::vector<Vec3> shadow_transmittance(const Scene& scene) {
  // Per-material value, then per triangle. A transparent surface lets `transparency` of the
  // light through, minus what its normal-incidence Fresnel reflectance F0 sends back, tinted
  // towards its diffuse colour the less transparent it is (so a semi-solid block casts a
  // coloured, darker shadow and clear glass an almost white one). Opaque surfaces give 0.
  std::vector<Vec3> per_material(scene.materials.size());
  for (size_t i = 0; i < scene.materials.size(); ++i) {
    const Material& m = scene.materials[i];
    const float tr = std::clamp(m.transparency, 0.0f, 1.0f);
    if (tr <= 0.0f) continue;
    const float r0 = (m.ior - 1.0f) / (m.ior + 1.0f);
    const float f0 = std::clamp(r0 * r0, 0.0f, 1.0f);
    const float mx = max_component(m.diffuse);
    const Vec3 colour = mx > 0.0f ? max(m.diffuse / mx, Vec3{0.0f}) : Vec3{1.0f};
    const Vec3 tint = lerp(Vec3{1.0f}, colour, 1.0f - tr);
    const Vec3 t = tint * (tr * (1.0f - f0));
    per_material[i] = min(max(t, Vec3{0.0f}), Vec3{1.0f});
  }
  std::vector<Vec3> out(scene.triangle_count());
  for (size_t t = 0; t < out.size() && t < scene.material_ids.size(); ++t) {
    const uint32_t id = scene.material_ids[t];
    if (id < per_material.size()) out[t] = per_material[id];
  }
  return out;
}

namespace {

constexpr int kMaxMedia = 6;          ///< nesting depth of dielectric media tracked per path
constexpr float kMinWeight = 1e-3f;   ///< paths whose throughput drops below this are pruned
constexpr int kMaxDepthCap = 64;      ///< sanity cap for max_reflect / max_refract
constexpr int kMaxDimension = 32768;
constexpr uint64_t kMaxFilmBytes = uint64_t{2} << 30;  ///< 2 GiB of film planes

/// Material ids of the media a path is inside, innermost last.
struct MediumStack {
  uint32_t ids[kMaxMedia] = {};
  int count = 0;

  int top() const { return count > 0 ? static_cast<int>(ids[count - 1]) : -1; }
  void push(uint32_t id) {
    if (count < kMaxMedia) {
      ids[count++] = id;
    } else {  // too deep: forget the outermost medium rather than the newest one
      std::memmove(ids, ids + 1, sizeof(uint32_t) * (kMaxMedia - 1));
      ids[kMaxMedia - 1] = id;
    }
  }
  /// Removes the innermost occurrence of \p id; returns false when the path was not inside it.
  bool remove(uint32_t id) {
    for (int i = count - 1; i >= 0; --i)
      if (ids[i] == id) {
        for (int j = i; j + 1 < count; ++j) ids[j] = ids[j + 1];
        --count;
        return true;
      }
    return false;
  }
};

/// A path segment without its ray: the rays of a wavefront live in an array of their own, which
/// is what the tracer takes, so a wavefront is traced without being copied.
struct PathState {
  Vec3 weight;       ///< throughput from the camera to this segment
  uint32_t pixel;    ///< index inside the tile
  uint32_t global;   ///< index in the film
  uint8_t reflect_depth;
  uint8_t refract_depth;
  /// The path's bounce history (1, then a bit per bounce: 0 mirror, 1 refraction; saturates):
  /// segments with the same history at neighbouring pixels are coherent rays (see TraceOrder).
  uint16_t history;
  MediumStack media;
  /// The voxel (Hit::prim) this segment leaves, which it passes through (kNoHit: none; always
  /// for triangles). Secondary rays start a few ulps off a voxel's surface, inside a contour
  /// slab thicker than that: without this they would hit the same voxel again at tmin.
  uint32_t leave = kNoHit;

  bool primary() const { return history == 1; }
};

/// Child history of \p h after a mirror (0) or refraction (1) bounce; saturates at 15 bounces.
constexpr uint16_t next_history(uint16_t h, unsigned bit) {
  return h >= 0x8000u ? h : static_cast<uint16_t>((h << 1) | bit);
}

/// The order in which a wavefront (or shadow batch) is handed to the tracer: grouped by a
/// coherence key (bounce history; for shadow rays also the light), stable inside a group. The
/// integrator builds rays in pixel order, interleaving kinds (a hit's mirror ray, then its
/// refraction ray; its shadow rays to each light in turn), and a tracer that takes runs of
/// consecutive similar rays as packets sees only half-coherent runs that way. Tracing in key
/// order and scattering the results back leaves shading, and so the image, unchanged bit for
/// bit: only the order of the tracer's independent queries changes.
struct TraceOrder {
  static constexpr size_t kMaxGroups = 32;  ///< keys beyond this many share the last group
  std::vector<uint32_t> order;              ///< trace position -> wavefront index
  uint32_t keys[kMaxGroups] = {};
  uint32_t counts[kMaxGroups + 1] = {};

  // build() and trace_in_order() are out of line: render_tile is flattened, and a frame within 15
  // bounces never runs them (history order instead), so inlined they only took code space in its
  // hot loop; with them and the sphere lights outside, a pool water frame is about 3% faster
  // (BENCHMARKS.md, 2026-12-05 evening).

  /// Fills `order` from per-ray keys; false when it would be the identity (nothing to do).
  [[gnu::noinline]] bool build(std::span<const uint32_t> key) {
    const size_t n = key.size();
    std::vector<uint8_t>& g = group_;
    g.resize(n);
    size_t groups = 0, last = 0;
    bool sorted = true;  // groups met in first-appearance order, each in one run: identity
    std::fill(counts, counts + kMaxGroups + 1, 0u);
    for (size_t i = 0; i < n; ++i) {
      if (groups == 0 || keys[last] != key[i]) [[unlikely]] {  // a new run
        size_t k = 0;
        while (k < groups && keys[k] != key[i]) ++k;
        if (k == groups) {
          if (groups < kMaxGroups) keys[groups++] = key[i];
          else k = kMaxGroups - 1;
        }
        sorted = sorted && k >= last;
        last = k;
      }
      g[i] = static_cast<uint8_t>(last);
      ++counts[last + 1];
    }
    if (groups <= 1 || sorted) return false;
    for (size_t k = 1; k <= groups; ++k) counts[k] += counts[k - 1];
    order.resize(n);
    for (size_t i = 0; i < n; ++i) order[counts[g[i]]++] = static_cast<uint32_t>(i);
    return true;
  }

  /// Traces \p rays in `order` and scatters the results back: \p trace(sorted rays, sorted
  /// results) fills one result per ray, \p out receives them in the rays' own positions.
  /// \p sorted_rays and \p sorted_out are scratch.
  template <class Result, class Trace>
  [[gnu::noinline]] void trace_in_order(std::span<const Ray> rays, std::vector<Ray>& sorted_rays,
                                        std::vector<Result>& sorted_out, std::span<Result> out, Trace&& trace) const {
    const size_t n = order.size();
    sorted_rays.resize(n);
    sorted_out.assign(n, Result{});
    for (size_t j = 0; j < n; ++j) sorted_rays[j] = rays[order[j]];
    trace(std::span<const Ray>(sorted_rays), std::span<Result>(sorted_out));
    // every entry of out[0, n) written below: `order` is a permutation
    for (size_t j = 0; j < n; ++j) out[order[j]] = sorted_out[j];
  }

 private:
  std::vector<uint8_t> group_;
};

/// What shading needs of a material. Computed once per render for the scene's materials
/// (triangle hits), and per hit for voxels, whose colour, reflectivity, transparency and ior are
/// the voxel's own. The expressions are the ones evaluated per hit before this was hoisted, so
/// every number is the same bit for bit.
struct ShadeMaterial {
  Vec3 kd;        ///< diffuse * local
  Vec3 specular;
  Vec3 emission;
  Vec3 base;      ///< emission + ambient * diffuse * local: what every hit adds to its pixel
  float phong_exponent = 0.0f;
  /// powf(nh, phong_exponent) is exactly +0 for 0 < nh < spec_zero_below (0: no shortcut).
  float spec_zero_below = 0.0f;
  /// whole_exponent(phong_exponent): non-zero when the power is computed by squaring.
  uint32_t phong_int = 0;
  float refl = 0.0f, trans = 0.0f;  ///< mirror and dielectric weights, clamped and normalised
  float ior = 1.0f;
  bool has_spec = false;
  bool lit = false;  ///< whether a light can add anything (kd or the specular colour non-zero)
};

/// A mirror or dielectric hit, recorded by shade_hit(); its directions are evaluated for the whole
/// wavefront (render::bounce_block(), rows in Scratch::bounce_rows, same index) and its rays made
/// by bounce(), both after the shading loop (see render_tile).
struct Bounce {
  Vec3 weight;  ///< the segment's throughput after Beer-Lambert
  float refl, trans;  ///< the material's mirror and dielectric weights
  float eta;          ///< relative index of refraction (incident over transmitted side)
  uint32_t ray;       ///< wavefront index of the segment (its ray and PathState)
  uint32_t leave;     ///< PathState::leave of the rays it makes
  MediumStack media;  ///< the media a refraction ray is in (trans > 0 only)
};

/// A shadow ray's payload: the radiance it brings to its pixel when unoccluded.
struct ShadowRequest {
  Vec3 contrib;
  uint32_t pixel;  ///< index inside the tile
  uint32_t slot;   ///< where its ray (and transmittance) sits in the traced batch
};

/// Grows \p v to at least \p n entries (never shrinks: the vectors below are storage sized to the
/// largest batch so far, their live length is a count of its own).
template <class T>
void ensure_size(std::vector<T>& v, size_t n) {
  if (v.size() < n) v.resize(n);
}

/// Per-thread storage of a tile's wavefronts. The wavefront arrays and the shadow batch are
/// written by index up to a bound known before shading (2 rays and shadow_per_hit shadow rays per
/// hit), not push_back'ed: the live lengths are n_rays, n_next and n_shadow.
struct Scratch {
  std::vector<Ray> rays, next_rays;  ///< the wavefront being traced and the one being built
  std::vector<PathState> paths, next_paths;
  size_t n_rays = 0, n_next = 0;
  std::vector<Ray> refr_rays;  ///< history order: the refraction rays of the run being shaded
  std::vector<PathState> refr_paths;
  size_t n_refr = 0;
  std::vector<Hit> hits;
  std::vector<Ray> shadow_rays;
  std::vector<ShadowRequest> shadow_req;
  std::vector<Vec3> shadow_t;
  size_t n_shadow = 0;
  std::vector<Vec3> accum;
  /// The wavefront's additions to accum in shading order (render_tile adds them after the
  /// lights are evaluated, so every pixel's sum keeps its order): a sky or emission + ambient
  /// term, then for a lit hit (lit != kNotLit) its lights.
  struct Addition {
    Vec3 add;
    uint32_t pixel;
    uint32_t lit;  ///< index in `lit`, or kNotLit
  };
  static constexpr uint32_t kNotLit = 0xFFFFFFFFu;
  std::vector<Addition> additions;
  size_t n_additions = 0;
  /// A gradient sky's misses: their additions (holding the throughput until then) get
  /// weight * radiance after the shading loop, from sky_rows (render::kSkyRows rows, blocked).
  std::vector<uint32_t> sky_additions;
  size_t n_sky = 0;
  std::vector<float> sky_rows;
  std::vector<Bounce> bounces;  ///< the wavefront's mirror / dielectric hits, in shading order
  size_t n_bounces = 0;
  std::vector<float> exp_e;  ///< per ray in an absorbing medium: Beer-Lambert exponents, then transmittance
  std::vector<float> bounce_rows;  ///< their render::BounceRow rows, blocked (render::block_offset)
  render::LitPoints lit;  ///< the wavefront's lit hits
  std::vector<uint32_t> lit_global;   ///< per lit hit: its pixel's index in the film
  std::vector<uint16_t> lit_history;  ///< per lit hit: its path's history
  std::vector<Vec3> columns;  ///< per tile column: PinholeCamera::column of its pixel centre
  std::vector<uint64_t> cost;
  std::vector<uint32_t> skip;  ///< per ray: material of the voxel medium it is in (kNoHit: none)
  std::vector<uint32_t> skip_prim;  ///< per ray: the voxel it leaves (PathState::leave)
  std::vector<uint32_t> shadow_key;  ///< per shadow ray: coherence key (history, light)
  /// History order: per light, the next free slot of its region of the shadow batch (light L's
  /// region starts at n * Context::light_first_sample[L] for a wavefront of n rays).
  std::vector<size_t> light_cursor;
  std::vector<uint32_t> key;         ///< per wavefront ray: coherence key (history)
  TraceOrder trace_order;
  std::vector<Ray> sorted_rays;      ///< a batch in trace order
  std::vector<Hit> sorted_hits;
  std::vector<Vec3> sorted_t;
  ShadeMaterial voxel_material;  ///< the material of the voxel hit being shaded
  /// Index into Context::shade whose constant fields voxel_material holds (SIZE_MAX: none yet).
  size_t voxel_material_index = SIZE_MAX;
  uint32_t voxel_prim = kNoHit;  ///< the voxel whose material voxel_material holds (kNoHit: none)
  uint32_t voxel_material_id = 0;  ///< its VoxelAttributes::material
};


float to_unit_float(uint32_t x) { return static_cast<float>(x >> 8) * (1.0f / 16777216.0f); }

/// The largest nh for which the Blinn-Phong power nh^e is certainly rounded to +0 by powf, so the
/// call can be skipped without changing a bit: below 2^(-160 / e) the exact power is below
/// 2^-160, far under half the smallest subnormal (2^-150); glibc's powf sees e * log2(nh) <= -150
/// there and returns +0 from its underflow path. Checked against powf itself; 0 turns it off.
float spec_zero_below(float e) {
  if (!(e > 0.0f) || !std::isfinite(e)) return 0.0f;
  const float t = std::exp2(-160.0f / e);
  if (!(t > 0.0f) || !(t < 1.0f)) return 0.0f;
  const float at = std::pow(t, e);
  return (at == 0.0f && !std::signbit(at)) ? t : 0.0f;
}

/// Fills the per-hit part of \p sm (energy split, kd, base, ior) from a surface's diffuse colour,
/// reflectivity, transparency and ior; \p sm already holds its material's specular, exponent and
/// emission.
void finish_shade_material(ShadeMaterial& sm, const Vec3& diffuse, float reflectivity, float transparency,
                           float ior, const Vec3& ambient) {
  float refl = std::clamp(reflectivity, 0.0f, 1.0f);
  float trans = std::clamp(transparency, 0.0f, 1.0f);
  if (refl + trans > 1.0f) {
    const float k = 1.0f / (refl + trans);
    refl *= k;
    trans *= k;
  }
  const float local = std::max(0.0f, 1.0f - refl - trans);
  sm.refl = refl;
  sm.trans = trans;
  sm.ior = ior;
  sm.kd = diffuse * local;
  sm.base = sm.emission + ambient * diffuse * local;
  sm.lit = !(max_component(sm.kd) <= 0.0f && !sm.has_spec);
}

ShadeMaterial make_shade_material(const Material& m, const Vec3& ambient) {
  ShadeMaterial sm;
  sm.specular = m.specular;
  sm.emission = m.emission;
  sm.phong_exponent = m.phong_exponent;
  sm.spec_zero_below = spec_zero_below(m.phong_exponent);
  sm.phong_int = whole_exponent(m.phong_exponent);
  sm.has_spec = max_component(m.specular) > 0.0f;
  finish_shade_material(sm, m.diffuse, m.reflectivity, m.transparency, m.ior, ambient);
  return sm;
}

/// A light with what does not depend on the shading point computed once.
struct LightSetup {
  LightType type = LightType::Point;
  bool point = false;  ///< a point light (one sample at position)
  Vec3 power;          ///< color * intensity
  Vec3 l;              ///< directional: unit direction towards the light
  Vec3 position;
  float radius = 0.0f;
  float inv_n = 1.0f;
  std::vector<float> rr, phase;  ///< sphere: per sample k, disc radius and k * golden angle

  /// Evaluated for a wavefront's lit hits at once (LitPoints::evaluate_light): directional and
  /// point lights. Sphere lights are sampled hit by hit (sphere_light()).
  bool in_blocks() const { return type == LightType::Directional || point; }
};

/// Everything constant during one render.
struct Context {
  const Scene& scene;
  const Tracer& tracer;
  int width, height, tile, tiles_x;
  int max_reflect, max_refract;
  bool want_depth, want_normal, want_prim, want_cost;
  Material fallback;
  Film& film;
  /// Set when the tracer traces voxels: hits are then voxels (Hit::prim indexes the voxel
  /// attributes), shaded with their averaged numbers over their largest triangle's material.
  const VoxelTracer* voxels = nullptr;
  bool shadows = true;  ///< false: light contributions are added without a shadow ray
  bool group_rays = true;  ///< trace batches in TraceOrder (RenderOptions::group_coherent_rays)
  /// Wavefronts are built in history order, every history one contiguous run, so they are traced
  /// as they are, without a TraceOrder pass. Shading a run of one history h emits its mirror rays
  /// (history 2h) in order, then its refraction rays (2h + 1): the next wavefront is in history
  /// order again. A pixel has at most one segment of each history (a history is its path's whole
  /// bounce sequence) as long as no history saturates, so a pixel's own segments keep their
  /// order, and with them every addition to its colour: the film is the same bit for bit as in
  /// emission order. On when group_rays and a path cannot bounce 15 times (else TraceOrder).
  bool history_order = false;
  bool vertex_normals = false;  ///< the scene has one normal per vertex
  std::vector<ShadeMaterial> shade{};///< per scene material, then the fallback material
  std::vector<uint8_t> absorbing{};  ///< per scene material: some absorption coefficient > 0
  std::vector<Vec3> neg_absorption{};  ///< per scene material: -absorption, 0 where absorption <= 0
  bool any_absorbing = false;
  std::vector<LightSetup> lights{};  ///< lights that can contribute (power > 0)
  size_t shadow_per_hit = 0;          ///< most shadow rays one hit shoots (one per light sample)
  std::vector<size_t> light_first_sample{};  ///< per light: samples of the lights before it
  // The sizes the shading loop checks indices against, as plain numbers (a vector's size is two
  // loads, a subtraction and, for the triangles, a division per check, redone after every call
  // the compiler cannot see into).
  size_t n_triangles = 0, n_materials = 0, n_material_ids = 0, n_lights = 0;
  /// Every light is evaluated in blocks (LightSetup::in_blocks()). Else some sphere light reads
  /// Scratch::lit_global, which is only written then.
  bool block_lights_only = true;
  /// Scratch::lit_history is read (the shadow rays' coherence keys, when TraceOrder groups them):
  /// else not written per lit hit.
  bool keep_lit_history = false;

  /// Sets the numbers and flags above (after `lights` and the options are set).
  void count() {
    n_triangles = scene.triangle_count();
    n_materials = scene.materials.size();
    n_material_ids = scene.material_ids.size();
    n_lights = lights.size();
    keep_lit_history = shadows && group_rays && !history_order;
    block_lights_only = std::all_of(lights.begin(), lights.end(), [](const LightSetup& l) { return l.in_blocks(); });
  }

  /// Whether a hit record refers to something this context can shade.
  bool valid(const Hit& hit) const {
    if (!hit.hit()) return false;
    return voxels ? true : hit.prim < n_triangles;
  }

  /// Index into `shade` of material id \p id (the fallback for an invalid id).
  size_t shade_index(uint32_t id) const { return id < n_materials ? id : n_materials; }
  uint32_t material_id(uint32_t prim) const { return prim < n_material_ids ? scene.material_ids[prim] : 0xFFFFFFFFu; }
  float medium_ior(int id) const {
    return (id >= 0 && static_cast<size_t>(id) < n_materials) ? scene.materials[static_cast<size_t>(id)].ior : 1.0f;
  }
  /// Whether medium \p id attenuates (Beer-Lambert with some coefficient > 0); `absorbing` has one
  /// entry per scene material.
  bool absorbs(int id) const { return id >= 0 && static_cast<size_t>(id) < n_materials && absorbing[static_cast<size_t>(id)]; }
};

/// The Beer-Lambert exponents of a segment of length \p dist inside absorbing medium \p id
/// (Context::absorbs), written to \p e: their exponentials (render::exp_in_place, a wavefront's
/// at once) are its transmittance, channel by channel the same numbers as
/// sigma <= 0 ? 1 : (finite dist ? std::exp(-sigma * dist) : 0).
void medium_exponents(const Context& ctx, int id, float dist, float* e) {
  const Vec3& ns = ctx.neg_absorption[static_cast<size_t>(id)];  // -sigma, or 0 where sigma <= 0
  if (std::isfinite(dist)) {
    e[0] = ns.x * dist, e[1] = ns.y * dist, e[2] = ns.z * dist;
  } else {  // e^0 = 1 where nothing attenuates, e^-inf = 0 elsewhere
    e[0] = ns.x == 0.0f ? 0.0f : -kInf, e[1] = ns.y == 0.0f ? 0.0f : -kInf, e[2] = ns.z == 0.0f ? 0.0f : -kInf;
  }
}

/// The per-pixel rotation of the sphere-light sample spiral (only sphere_light() computes it, so
/// it is never hoisted into the light loop of every hit).
float sample_rotation(uint32_t global_pixel) {
  return 2.0f * kPi * to_unit_float(hash_u32(global_pixel * 0x9E3779B9u + 0x632BE5ABu));
}

/// The samples of sphere light \p light at lit point \p sq of film pixel \p global_pixel: n
/// points of a Vogel (golden-angle Fibonacci) spiral on the disc the sphere presents to the point,
/// rotated by a per-pixel hash so neighbouring pixels see different but deterministic patterns.
/// Each sample carries 1/n of the intensity; \p emit(contribution, sample point) takes each lit one. Out of
/// line (like the other paths a typical frame never takes): render_tile's hot loop stays small.
template <class Emit>
[[gnu::noinline]] void sphere_light(uint32_t global_pixel, const LightSetup& light, const render::LitPoint& sq,
                                    Emit&& emit) {
  const Vec3 axis = normalize(light.position - sq.p);
  Vec3 t, b;
  orthonormal_basis(axis == Vec3{} ? Vec3{0, 1, 0} : axis, t, b);
  const float rot = sample_rotation(global_pixel);
  const size_t n = light.rr.size();
  for (size_t k = 0; k < n; ++k) {
    const float phi = light.phase[k] + rot;
    const Vec3 qk = light.position + (t * std::cos(phi) + b * std::sin(phi)) * light.rr[k];
    const Vec3 to = qk - sq.p;
    const float d2 = dot(to, to);
    if (!(d2 > 0.0f)) continue;
    Vec3 c;
    if (!render::sample_light(sq, to * (1.0f / std::sqrt(d2)), light.power * (light.inv_n / d2), c)) continue;
    emit(c, qk);
  }
}

/// Queues the shadow ray \p shadow of light \p li for lit hit \p j at tile pixel \p pixel, with the
/// radiance \p c it brings when unoccluded. Written by index: render_tile sized the batch for
/// shadow_per_hit rays per hit. In history order each light's rays go to a region of their own,
/// in shading order, so the batch is one run per (light, history) without a TraceOrder pass;
/// else the rays sit in request order and, grouped, carry their coherence key (the path's
/// history and the light) for TraceOrder.
[[gnu::always_inline]] inline void add_shadow_ray(const Context& ctx, Scratch& s, uint32_t pixel, uint32_t j, size_t li,
                                                  const Vec3& c, const Ray& shadow) {
  const size_t k = s.n_shadow++;
  const size_t slot = ctx.history_order ? s.light_cursor[li]++ : k;
  s.shadow_rays[slot] = shadow;
  s.shadow_req[k] = ShadowRequest{c, pixel, static_cast<uint32_t>(slot)};
  if (ctx.keep_lit_history)  // only read where TraceOrder groups the batch
    s.shadow_key[k] = (uint32_t{s.lit_history[j]} << 8) | static_cast<uint32_t>(std::min<size_t>(li, 255));
}

/// Adds the direct lighting of every light at lit hit \p j of the wavefront (Scratch::lit,
/// whose directional and point lights were evaluated for all hits at once): straight to the
/// pixel without shadow rays, else as shadow-ray requests carrying the radiance they would
/// bring. Sphere lights, and hits whose Phong exponent is not whole, go through
/// render::sample_light() here, one sample at a time.
[[gnu::always_inline]] inline void shade_lights(const Context& ctx, Scratch& s, uint32_t pixel, uint32_t j) {
  const render::LitPoints& lit = s.lit;
  const bool one_by_one = lit.one_by_one(j);
  if (!one_by_one && ctx.block_lights_only) {
    // The common case, without the per-light kind checks: every light's contribution was found
    // by the blocks and goes straight to the pixel, or into a shadow ray from one origin.
    if (!ctx.shadows) {
      for (size_t li = 0; li < ctx.n_lights; ++li) {
        Vec3 c;
        if (lit.result(li, j, c)) s.accum[pixel] += c;
      }
      return;
    }
    // Its own lazy origin: sharing the general path's origin() lambda (declared before this
    // branch) cost the flattened render_tile 8 M more instructions per water frame.
    Vec3 org;
    bool have_org = false;
    for (size_t li = 0; li < ctx.n_lights; ++li) {
      Vec3 c;
      if (!lit.result(li, j, c)) continue;
      if (!have_org) {
        org = offset_ray_origin(lit.position(j), lit.normal(j));
        have_org = true;
      }
      const LightSetup& light = ctx.lights[li];
      add_shadow_ray(ctx, s, pixel, j, li, c,
                     light.type == LightType::Directional ? Ray{org, 0.0f, light.l, kInf}
                                                          : Ray{org, 0.0f, light.position - org, 1.0f});
    }
    return;
  }
  // The whole point, gathered from the arrays only where sample_light() needs it. Held in a
  // union that leaves it unconstructed until then: a declared LitPoint (or std::optional of one)
  // is zeroed first, which the x86-64-v3 clone of render_tile did for every lit hit with a
  // `rep stosq`, slow to start on Intel cores (that clone's water frame: 68.0 -> 58.1 ms).
  union Lazy {
    Lazy() {}
    render::LitPoint q;
  } lazy;
  bool have_q = false;
  const auto point = [&]() -> const render::LitPoint& {
    if (!have_q) {
      std::construct_at(&lazy.q, lit[j]);
      have_q = true;
    }
    return lazy.q;
  };
  // The shadow rays' origin, computed on first use (never without shadow rays).
  Vec3 org;
  bool have_org = false;
  const auto origin = [&]() -> const Vec3& {
    if (!have_org) {
      org = offset_ray_origin(lit.position(j), lit.normal(j));
      have_org = true;
    }
    return org;
  };
  const auto add = [&](const Vec3& c, const Ray& shadow, const LightSetup& light) {
    add_shadow_ray(ctx, s, pixel, j, static_cast<size_t>(&light - ctx.lights.data()), c, shadow);
  };

  for (size_t li = 0; li < ctx.n_lights; ++li) {
    const LightSetup& light = ctx.lights[li];
    Vec3 c;
    if (light.type == LightType::Directional) {
      if (!(one_by_one ? render::sample_light(point(), light.l, light.power, c) : lit.result(li, j, c))) continue;
      if (ctx.shadows) add(c, Ray{origin(), 0.0f, light.l, kInf}, light);
      else s.accum[pixel] += c;
      continue;
    }
    if (light.point) {
      if (one_by_one) {
        const Vec3 to = light.position - point().p;
        const float d2 = dot(to, to);
        if (!(d2 > 0.0f)) continue;
        if (!render::sample_light(point(), to * (1.0f / std::sqrt(d2)), light.power / d2, c)) continue;
      } else if (!lit.result(li, j, c)) {
        continue;
      }
      if (ctx.shadows) add(c, Ray{origin(), 0.0f, light.position - origin(), 1.0f}, light);
      else s.accum[pixel] += c;
      continue;
    }
    sphere_light(s.lit_global[j], light, point(), [&](const Vec3& sample_c, const Vec3& qk) {
      if (ctx.shadows) add(sample_c, Ray{origin(), 0.0f, qk - origin(), 1.0f}, light);
      else s.accum[pixel] += sample_c;
    });
  }
}

/// The wavefront's lighting and its additions to the pixels, in shading order: the directional
/// and point lights evaluated for all lit hits at once, then every addition in turn.
[[gnu::always_inline]] inline void add_shading(const Context& ctx, Scratch& s) {
  if (s.lit.size() > 0)
    for (size_t li = 0; li < ctx.n_lights; ++li) {
      const LightSetup& light = ctx.lights[li];
      if (light.in_blocks())
        s.lit.evaluate_light(li, light.type == LightType::Directional, light.l, light.position, light.power);
    }
  for (size_t i = 0; i < s.n_additions; ++i) {
    const Scratch::Addition& a = s.additions[i];
    s.accum[a.pixel] += a.add;
    if (a.lit != Scratch::kNotLit) shade_lights(ctx, s, a.pixel, a.lit);
  }
}

/// What shading needs of a hit: position, normals, material.
struct Surface {
  Vec3 p;        ///< on the surface up to rounding (what offset_ray_origin assumes)
  Vec3 ng;       ///< unit geometric normal as stored (not flipped)
  Vec3 ns;       ///< unit shading normal as stored, or zero (= ng)
  const ShadeMaterial* m;
  uint32_t material_id;
};

/// A triangle hit: position from the barycentrics (not org + t dir, so it lies on the triangle
/// up to rounding), interpolated vertex normals.
Surface triangle_surface(const Context& ctx, const Hit& hit) {
  const Scene& scene = ctx.scene;
  const uint32_t prim = hit.prim;
  const uint32_t i0 = scene.indices[3 * size_t{prim}], i1 = scene.indices[3 * size_t{prim} + 1],
                 i2 = scene.indices[3 * size_t{prim} + 2];
  const float w0 = 1.0f - hit.u - hit.v;
  Surface sf;
  sf.p = scene.positions[i0] * w0 + scene.positions[i1] * hit.u + scene.positions[i2] * hit.v;
  sf.ng = hit.ng;
  if (!(dot(sf.ng, sf.ng) > 0.0f) || !is_finite(sf.ng))
    sf.ng = normalize(cross(scene.positions[i1] - scene.positions[i0], scene.positions[i2] - scene.positions[i0]));
  sf.ns = Vec3{};
  if (ctx.vertex_normals)
    sf.ns = normalize(scene.normals[i0] * w0 + scene.normals[i1] * hit.u + scene.normals[i2] * hit.v);
  sf.material_id = ctx.material_id(prim);
  sf.m = &ctx.shade[ctx.shade_index(sf.material_id)];
  return sf;
}

/// A voxel hit: the voxel's averaged colour, reflectivity, transparency and ior over the
/// material of its largest triangle part (specular, Phong exponent, absorption, emission);
/// the normal the tracer reports (cube face or contour plane). Scratch::voxel_material holds the
/// material.
Surface voxel_surface(const Context& ctx, Scratch& s, const Ray& ray, const Hit& hit) {
  ShadeMaterial& storage = s.voxel_material;
  // The material depends on the voxel only: a hit on the voxel the previous voxel hit shaded
  // (neighbouring pixels on one coarse voxel; every pixel when the camera sits in one) reuses it.
  if (hit.prim != s.voxel_prim) {
    const VoxelAttributes& a = ctx.voxels->attributes(hit.prim);
    const size_t index = ctx.shade_index(a.material);
    const ShadeMaterial& base = ctx.shade[index];
    // The material's own fields (specular, exponent, emission) are copied only when the material
    // changes from the previous voxel hit: finish_shade_material rewrites every per-hit field.
    if (index != s.voxel_material_index) {
      storage = base;
      s.voxel_material_index = index;
    }
    finish_shade_material(storage, a.colour, a.reflectivity, a.transparency, a.transparency > 0.0f ? a.ior : base.ior,
                          ctx.scene.ambient);
    s.voxel_prim = hit.prim;
    s.voxel_material_id = a.material;
  }
  Surface sf;
  sf.p = ray.org + ray.dir * hit.t;
  sf.ng = hit.ng;
  if (!(dot(sf.ng, sf.ng) > 0.0f) || !is_finite(sf.ng)) sf.ng = -normalize(ray.dir);
  sf.ns = Vec3{};
  sf.m = &storage;
  sf.material_id = s.voxel_material_id;
  return sf;
}

/// Shades one hit: emission, ambient and lights go to the pixel / shadow batch; a mirror or
/// dielectric hit is recorded for bounce(), which makes its mirror and refraction rays.
void shade_hit(const Context& ctx, Scratch& s, const Ray& ray, const PathState& seg, uint32_t index,
               const Vec3& weight, const Surface& sf, uint32_t leave) {
  const Vec3& p = sf.p;
  // Every wavefront ray is unit length as it is made (the camera, reflect() and refract()
  // normalize their directions): normalizing it again here only cost a square root and a
  // division per hit.
  const Vec3& d = ray.dir;
  const Vec3& ng = sf.ng;
  const bool front = dot(d, ng) < 0.0f;  // arriving on the side the winding faces
  const Vec3 ng_f = front ? ng : -ng;    // geometric normal facing the incoming ray
  Vec3 ns = ng_f;
  if (sf.ns != Vec3{}) ns = dot(sf.ns, ng_f) < 0.0f ? -sf.ns : sf.ns;
  const Vec3& ns_f = ns;
  const ShadeMaterial& m = *sf.m;

  // Local shading: emission + ambient, and the hit's direct light (through the shadow batch),
  // added after the wavefront (add_shading).
  uint32_t lit = Scratch::kNotLit;
  if (m.lit) {
    render::LitPoint q;
    q.p = p;
    q.ng_f = ng_f;
    q.ns_f = ns_f;
    q.view_dir = d;
    q.weight = weight;
    q.kd = m.kd;
    q.specular = m.specular;
    q.exponent = m.phong_exponent;
    q.zero_below = m.spec_zero_below;
    q.phong_int = m.phong_int;
    q.has_spec = m.has_spec;
    lit = s.lit.add(q);
    if (!ctx.block_lights_only) s.lit_global[lit] = seg.global;
    if (ctx.keep_lit_history) s.lit_history[lit] = seg.history;
  }
  s.additions[s.n_additions++] = Scratch::Addition{weight * m.base, seg.pixel, lit};

  // Nothing to bounce unless the surface mirrors or transmits (the mirror and refraction
  // weights in bounce() are then both <= 0, or NaN: no ray either way). Field by field: an
  // aggregate is built on the stack by GCC and copied with wide loads that wait for the narrower
  // stores just made (store-forwarding stalls).
  if (!(m.refl > 0.0f || m.trans > 0.0f)) return;
  const size_t k = s.n_bounces++;
  Bounce& b = s.bounces[k];
  b.weight = weight;
  b.refl = m.refl;
  b.trans = m.trans;
  b.ray = index;
  b.leave = leave;
  float eta = 1.0f;  // no interface (fresnel_dielectric() is 0): mirror-only hits
  if (m.trans > 0.0f) {
    const uint32_t mid = sf.material_id;
    b.media = seg.media;
    float n1, n2;
    if (front) {  // entering the medium behind the surface
      n1 = ctx.medium_ior(seg.media.top());
      n2 = m.ior;
      b.media.push(mid);
    } else {      // leaving it
      n1 = m.ior;
      b.media.remove(mid);
      n2 = ctx.medium_ior(b.media.top());
    }
    eta = n1 / n2;
  }
  b.eta = eta;
  float* const cell = s.bounce_rows.data() + render::block_offset<render::kBounceRows>(0, k);
  const float in[render::kBounceInputs] = {d.x, d.y, d.z, ns_f.x, ns_f.y, ns_f.z, ng_f.x, ng_f.y, ng_f.z, eta,
                                           p.x, p.y, p.z};
  for (int r = 0; r < render::kBounceInputs; ++r) cell[static_cast<size_t>(r) * render::kBlock] = in[r];
}

/// The mirror and refraction rays of recorded hit \p k (segment \p seg, incoming direction \p d),
/// from the directions render::bounce_block() found for it: its mirror ray to the next wavefront,
/// its refraction ray after it (or, in history order, after the run's mirror rays). Called for
/// the recorded hits in shading order, so the rays are the same, in the same order, as when each
/// hit made them at once.
void bounce(const Context& ctx, Scratch& s, const Vec3& d, const PathState& seg, size_t k) {
  const Bounce& b = s.bounces[k];
  const float* const cell = s.bounce_rows.data() + render::block_offset<render::kBounceRows>(0, k);
  const auto at = [&](int r) { return cell[static_cast<size_t>(r) * render::kBlock]; };
  const Vec3 ng_f{at(render::kBounceGx), at(render::kBounceGy), at(render::kBounceGz)};
  const Vec3& weight = b.weight;
  float refl_w = b.refl;
  float refr_w = 0.0f;
  Vec3 refr_dir;
  if (b.trans > 0.0f) {
    const float trans = b.trans;
    float fr = at(render::kBounceFr);
    int32_t ok_bits;
    std::memcpy(&ok_bits, cell + static_cast<size_t>(render::kBounceOk) * render::kBlock, sizeof ok_bits);
    bool ok = ok_bits != 0;
    if (ok) refr_dir = Vec3{at(render::kBounceTx), at(render::kBounceTy), at(render::kBounceTz)};
    if (!ok && fr < 1.0f) {  // the shading normal bent the ray back: use the geometric one
      fr = detail::fresnel_dielectric(-dot(d, ng_f), b.eta);
      ok = fr < 1.0f && detail::refract(d, ng_f, b.eta, refr_dir) && dot(refr_dir, ng_f) < 0.0f;
    }
    if (!ok) fr = 1.0f;  // total internal reflection
    refl_w += trans * fr;
    refr_w = trans * (1.0f - fr);
  }

  if (refl_w > 0.0f && seg.reflect_depth < ctx.max_reflect) {
    const Vec3 w = weight * refl_w;
    if (max_component(w) >= kMinWeight) {
      const size_t r = s.n_next++;  // render_tile sized next_* for two rays per hit
      s.next_rays[r] = Ray{Vec3{at(render::kBounceAx), at(render::kBounceAy), at(render::kBounceAz)}, 0.0f,
                           Vec3{at(render::kBounceMx), at(render::kBounceMy), at(render::kBounceMz)}, kInf};
      s.next_paths[r] = PathState{w, seg.pixel, seg.global, static_cast<uint8_t>(seg.reflect_depth + 1),
                                  seg.refract_depth, next_history(seg.history, 0), seg.media, b.leave};
    }
  }
  if (refr_w > 0.0f && seg.refract_depth < ctx.max_refract) {
    const Vec3 w = weight * refr_w;
    if (max_component(w) >= kMinWeight) {
      // In history order (Context::history_order) a run's refraction rays wait in refr_* until
      // the run is shaded, then follow its mirror rays.
      std::vector<Ray>& rays = ctx.history_order ? s.refr_rays : s.next_rays;
      std::vector<PathState>& paths = ctx.history_order ? s.refr_paths : s.next_paths;
      const size_t r = ctx.history_order ? s.n_refr++ : s.n_next++;
      rays[r] = Ray{Vec3{at(render::kBounceBx), at(render::kBounceBy), at(render::kBounceBz)}, 0.0f, refr_dir, kInf};
      paths[r] = PathState{w, seg.pixel, seg.global, seg.reflect_depth,
                           static_cast<uint8_t>(seg.refract_depth + 1), next_history(seg.history, 1), b.media,
                           b.leave};
    }
  }
}

struct TileCounters {
  uint64_t primary = 0, secondary = 0, shadow = 0;
};

// Compiled three times (baseline x86-64; x86-64-v3, i.e. AVX2 and the VEX three-operand forms;
// x86-64-v4, AVX-512 with its 32 vector registers, which this large flattened function spills
// less with) with the shading it calls inlined, the right one chosen at load time: v3 took ~2.5%
// off a pool frame, v4 another ~4% on Zen 5. All give the same image bit for bit (no contraction
// into FMA: -ffp-contract=off; sqrt and division are correctly rounded either way; std::exp is
// the same library call).
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
[[gnu::flatten, gnu::target_clones("default", "arch=x86-64-v3", "arch=x86-64-v4")]]
#endif
void render_tile(const Context& ctx, const SkyEval& sky, Scratch& s, const PinholeCamera& camera,
                 int tile_index, TileCounters& counters) {
  const int tx = tile_index % ctx.tiles_x, ty = tile_index / ctx.tiles_x;
  const int x0 = tx * ctx.tile, y0 = ty * ctx.tile;
  const int x1 = std::min(x0 + ctx.tile, ctx.width), y1 = std::min(y0 + ctx.tile, ctx.height);
  const int tw = x1 - x0, th = y1 - y0;
  const size_t npix = static_cast<size_t>(tw) * static_cast<size_t>(th);

  s.accum.assign(npix, Vec3{});
  if (ctx.want_cost) s.cost.assign(npix, 0);
  // Primary rays in 4x4 pixel blocks: every 16 consecutive rays of the wavefront are neighbours,
  // which a tracer may trace as one packet (the BVH and the octree take two blocks at a time),
  // and so are the shadow rays their hits shoot. Each pixel's own segments keep their order, so the image is the same bit for bit.
  // The camera's per-column half of the direction is computed once per column of the tile
  // (PinholeCamera::column: the same sum in the same order as generate()).
  ensure_size(s.columns, static_cast<size_t>(tw));
  for (int x = x0; x < x1; ++x) s.columns[static_cast<size_t>(x - x0)] = camera.column(static_cast<float>(x) + 0.5f);
  ensure_size(s.rays, npix);
  ensure_size(s.paths, npix);
  {
    size_t k = 0;
    for (int by = y0; by < y1; by += 4)
      for (int bx = x0; bx < x1; bx += 4)
        for (int y = by; y < std::min(by + 4, y1); ++y) {
          const float py = static_cast<float>(y) + 0.5f;
          for (int x = bx; x < std::min(bx + 4, x1); ++x, ++k) {
            s.rays[k] = camera.ray_from_column(s.columns[static_cast<size_t>(x - x0)], py);
            PathState& ps = s.paths[k];
            ps = PathState{};
            ps.weight = Vec3{1.0f};
            ps.pixel = static_cast<uint32_t>((y - y0) * tw + (x - x0));
            ps.global = static_cast<uint32_t>(y) * static_cast<uint32_t>(ctx.width) + static_cast<uint32_t>(x);
            ps.reflect_depth = 0;
            ps.refract_depth = 0;
            ps.history = 1;
          }
        }
    s.n_rays = k;
  }
  counters.primary += npix;
  s.voxel_material_index = SIZE_MAX;
  s.voxel_prim = kNoHit;

  while (s.n_rays != 0) {
    const size_t n = s.n_rays;
    const std::span<const Ray> rays(s.rays.data(), n);
    const std::span<const PathState> paths(s.paths.data(), n);
    // Voxel media (seed 001): a ray inside a medium passes the voxels of that medium's material.
    std::span<const uint32_t> skip, skip_prim;
    if (ctx.voxels) {
      s.skip.resize(n);
      s.skip_prim.resize(n);
      bool any = false, any_prim = false;
      for (size_t i = 0; i < n; ++i) {
        const int top = paths[i].media.top();
        s.skip[i] = top < 0 ? kNoHit : static_cast<uint32_t>(top);
        s.skip_prim[i] = paths[i].leave;
        any = any || top >= 0;
        any_prim = any_prim || paths[i].leave != kNoHit;
      }
      if (any) skip = s.skip;
      if (any_prim) skip_prim = s.skip_prim;
    }
    const auto trace = [&](std::span<const Ray> r, std::span<const uint32_t> skips,
                           std::span<const uint32_t> skip_prims, std::span<Hit> hits, TraceStats* ts) {
      if (!skips.empty() || !skip_prims.empty())
        ctx.voxels->intersect_skipping(r, skips, hits, ts, skip_prims);
      else
        ctx.tracer.intersect(r, hits, ts);
    };
    if (ctx.want_cost) [[unlikely]] {
      // Per-ray queries so the node visits can be charged to their pixel.
      s.hits.assign(n, Hit{});
      for (size_t i = 0; i < n; ++i) {
        TraceStats ts;
        trace(rays.subspan(i, 1), skip.empty() ? skip : skip.subspan(i, 1),
              skip_prim.empty() ? skip_prim : skip_prim.subspan(i, 1),
              std::span<Hit>(&s.hits[i], 1), &ts);
        s.cost[paths[i].pixel] += ts.nodes_visited;
      }
    } else {
      // (The primary wavefront has one history: nothing to order. Voxel tracers group their
      // batches by direction octant themselves, which is the same grouping here.)
      bool reorder = false;
      if (ctx.group_rays && !ctx.history_order && !paths.front().primary()) {
        s.key.resize(n);
        for (size_t i = 0; i < n; ++i) s.key[i] = paths[i].history;
        reorder = s.trace_order.build(s.key);
      }
      if (reorder) {  // coherent rays side by side (TraceOrder; never for voxels: no skips)
        s.hits.resize(n);
        s.trace_order.trace_in_order(rays, s.sorted_rays, s.sorted_hits, std::span<Hit>(s.hits),
                                     [&](std::span<const Ray> r, std::span<Hit> h) { trace(r, {}, {}, h, nullptr); });
      } else {
        s.hits.resize(n);  // the tracer writes every hit (a miss too: Tracer::intersect)
        trace(rays, skip, skip_prim, s.hits, nullptr);
      }
    }

    // Room for everything shading can emit: two rays and shadow_per_hit shadow rays per hit.
    ensure_size(s.next_rays, 2 * n);
    ensure_size(s.next_paths, 2 * n);
    s.n_next = 0;
    if (ctx.shadows) {
      const size_t most = n * ctx.shadow_per_hit;
      ensure_size(s.shadow_rays, most);
      ensure_size(s.shadow_req, most);
      if (ctx.group_rays && !ctx.history_order) ensure_size(s.shadow_key, most);
      if (ctx.history_order) {
        s.light_cursor.resize(ctx.lights.size());
        for (size_t l = 0; l < ctx.lights.size(); ++l) s.light_cursor[l] = n * ctx.light_first_sample[l];
      }
    }
    s.n_shadow = 0;
    if (ctx.history_order) {
      ensure_size(s.refr_rays, n);
      ensure_size(s.refr_paths, n);
    }
    s.n_refr = 0;
    ensure_size(s.additions, n);
    s.n_additions = 0;
    ensure_size(s.bounces, n);
    s.n_bounces = 0;
    const size_t blocks = (n + render::kBlock - 1) / render::kBlock;
    ensure_size(s.bounce_rows, blocks * render::kBounceRows * render::kBlock);
    ensure_size(s.sky_additions, n);
    ensure_size(s.sky_rows, blocks * render::kSkyRows * render::kBlock);
    s.n_sky = 0;
    s.lit.reset(n, ctx.lights.size());
    ensure_size(s.lit_global, n);
    ensure_size(s.lit_history, n);
    // History order: a run's refraction rays follow its mirror rays.
    const auto flush_refractions = [&] {
      std::copy_n(s.refr_rays.begin(), s.n_refr, s.next_rays.begin() + static_cast<ptrdiff_t>(s.n_next));
      std::copy_n(s.refr_paths.begin(), s.n_refr, s.next_paths.begin() + static_cast<ptrdiff_t>(s.n_next));
      s.n_next += s.n_refr;
      s.n_refr = 0;
    };
    // Beer-Lambert over the segments inside absorbing media (a factor of exactly 1 outside:
    // skipped): their transmittances first, all exponentials at once, in the loop's order.
    // Unit directions: the distance is t.
    size_t n_exp = 0;
    if (ctx.any_absorbing) {
      ensure_size(s.exp_e, 3 * n);
      for (size_t i = 0; i < n; ++i) {
        const int top = paths[i].media.top();
        if (!ctx.absorbs(top)) continue;
        const Hit& hit = s.hits[i];
        medium_exponents(ctx, top, ctx.valid(hit) ? hit.t : kInf, s.exp_e.data() + 3 * n_exp++);
      }
      render::exp_in_place(s.exp_e.data(), 3 * n_exp);
      n_exp = 0;
    }
    for (size_t i = 0; i < n; ++i) {
      const Ray& ray = rays[i];
      const PathState& seg = paths[i];
      const Hit& hit = s.hits[i];
      const bool valid = ctx.valid(hit);
      Vec3 weight = seg.weight;
      const int top = seg.media.top();
      if (ctx.absorbs(top)) {
        const float* const att = s.exp_e.data() + 3 * n_exp++;
        weight *= Vec3{att[0], att[1], att[2]};
      }
      const size_t gp = seg.global;
      if (seg.primary()) {
        if (ctx.want_depth) ctx.film.depth[gp] = valid ? hit.t * length(ray.dir) : kInf;
        if (ctx.want_prim) ctx.film.prim_id[gp] = valid ? hit.prim : kNoHit;
      }
      if (!valid) {
        if (sky.gradient()) {  // weight * sky.radiance(ray.dir), a block at a time after the loop
          const size_t k = s.n_sky++;
          s.sky_additions[k] = static_cast<uint32_t>(s.n_additions);
          float* const cell = s.sky_rows.data() + render::block_offset<render::kSkyRows>(0, k);
          cell[0] = ray.dir.x;
          cell[render::kBlock] = ray.dir.y;
          cell[2 * render::kBlock] = ray.dir.z;
          s.additions[s.n_additions++] = Scratch::Addition{weight, seg.pixel, Scratch::kNotLit};
        } else {
          s.additions[s.n_additions++] = Scratch::Addition{weight * sky.radiance(ray.dir), seg.pixel, Scratch::kNotLit};
        }
        continue;
      }
      if (max_component(weight) <= 0.0f) continue;
      const Surface sf = ctx.voxels ? voxel_surface(ctx, s, ray, hit) : triangle_surface(ctx, hit);
      shade_hit(ctx, s, ray, seg, static_cast<uint32_t>(i), weight, sf, ctx.voxels ? hit.prim : kNoHit);
      if (seg.primary() && ctx.want_normal) {
        Vec3 nrm = sf.ns != Vec3{} ? sf.ns : sf.ng;
        if (dot(nrm, ray.dir) > 0.0f) nrm = -nrm;  // facing the camera
        ctx.film.normal[gp] = nrm;
      }
    }

    // The gradient sky's misses: SkyEval::gradient_t() a block at a time (lane by lane the same
    // normalisation, clamp and square root), then each addition's weight times the radiance.
    render::for_each_block<render::kSkyRows>(s.sky_rows.data(), s.n_sky, 3, render::gradient_t_block);
    for (size_t k = 0; k < s.n_sky; ++k) {
      Vec3& add = s.additions[s.sky_additions[k]].add;
      add = add * sky.gradient_radiance(s.sky_rows[render::block_offset<render::kSkyRows>(3, k)]);
    }

    // The recorded mirror and dielectric hits: their directions a block at a time, then their
    // rays in shading order (in history order a run's refractions after its mirror rays: a run
    // ends where the bounce history changes). Evaluated hit by hit inside the loop above, these
    // dependent chains of square roots and divisions were waited on one hit after another.
    const size_t nb = s.n_bounces;
    render::for_each_block<render::kBounceRows>(s.bounce_rows.data(), nb, render::kBounceInputs, render::bounce_block);
    uint16_t run = paths.front().history;
    for (size_t b = 0; b < nb; ++b) {
      const uint32_t i = s.bounces[b].ray;
      const PathState& seg = paths[i];
      if (seg.history != run) {
        if (s.n_refr != 0) flush_refractions();
        run = seg.history;
      }
      bounce(ctx, s, rays[i].dir, seg, b);
    }
    if (s.n_refr != 0) flush_refractions();
    add_shading(ctx, s);

    const size_t ns = s.n_shadow;
    if (ns > 0 && ctx.history_order) {
      // One region per light, each in shading order: (light, history) runs side by side.
      ensure_size(s.shadow_t, n * ctx.shadow_per_hit);
      if (ctx.want_cost) [[unlikely]] {
        for (size_t i = 0; i < ns; ++i) {
          TraceStats ts;
          const size_t slot = s.shadow_req[i].slot;
          ctx.tracer.transmittance(std::span<const Ray>(&s.shadow_rays[slot], 1), std::span<Vec3>(&s.shadow_t[slot], 1),
                                   &ts);
          s.cost[s.shadow_req[i].pixel] += ts.nodes_visited;
        }
      } else {
        for (size_t l = 0; l < ctx.lights.size(); ++l) {
          const size_t first = n * ctx.light_first_sample[l], count = s.light_cursor[l] - first;
          if (count == 0) continue;
          const std::span<Vec3> t(s.shadow_t.data() + first, count);  // every ray written (Tracer::transmittance)
          ctx.tracer.transmittance(std::span<const Ray>(s.shadow_rays.data() + first, count), t);
        }
      }
      for (size_t i = 0; i < ns; ++i)
        s.accum[s.shadow_req[i].pixel] += s.shadow_req[i].contrib * s.shadow_t[s.shadow_req[i].slot];
      counters.shadow += ns;
    } else if (ns > 0) {
      const std::span<const Ray> shadow_rays(s.shadow_rays.data(), ns);
      s.shadow_t.resize(ns);  // the tracer writes every ray's transmittance
      if (ctx.want_cost) [[unlikely]] {
        for (size_t i = 0; i < ns; ++i) {
          TraceStats ts;
          ctx.tracer.transmittance(shadow_rays.subspan(i, 1), std::span<Vec3>(&s.shadow_t[i], 1), &ts);
          s.cost[s.shadow_req[i].pixel] += ts.nodes_visited;
        }
      } else if (ctx.group_rays && s.trace_order.build(std::span<const uint32_t>(s.shadow_key.data(), ns))) {
        // coherent rays side by side (TraceOrder)
        s.trace_order.trace_in_order(shadow_rays, s.sorted_rays, s.sorted_t, std::span<Vec3>(s.shadow_t),
                                     [&](std::span<const Ray> r, std::span<Vec3> t) { ctx.tracer.transmittance(r, t); });
      } else {
        ctx.tracer.transmittance(shadow_rays, s.shadow_t);
      }
      for (size_t i = 0; i < ns; ++i) s.accum[s.shadow_req[i].pixel] += s.shadow_req[i].contrib * s.shadow_t[i];
      counters.shadow += ns;
    }
    counters.secondary += s.n_next;
    std::swap(s.rays, s.next_rays);
    std::swap(s.paths, s.next_paths);
    s.n_rays = s.n_next;
  }

  for (int y = y0; y < y1; ++y)
    for (int x = x0; x < x1; ++x) {
      const size_t i = static_cast<size_t>(y - y0) * static_cast<size_t>(tw) + static_cast<size_t>(x - x0);
      const size_t gp = static_cast<size_t>(y) * static_cast<size_t>(ctx.width) + static_cast<size_t>(x);
      ctx.film.color[gp] = s.accum[i];
      if (ctx.want_cost) ctx.film.cost[gp] = static_cast<uint32_t>(std::min<uint64_t>(s.cost[i], 0xFFFFFFFFu));
    }
}

}  // namespace

Film render_whitted(const Scene& scene, const Tracer& tracer, const RenderOptions& options,
                    RenderStats* stats) {
  Film film;
  render_whitted(scene, tracer, options, film, stats);
  return film;
}

void check_image_size(int width, int height, std::span<const Aov> aovs) {
  const int w = width, h = height;
  if (w <= 0 || h <= 0 || w > kMaxDimension || h > kMaxDimension)
    throw Error("invalid image size " + std::to_string(w) + "x" + std::to_string(h) +
                " (each side must be 1.." + std::to_string(kMaxDimension) + ")");
  uint64_t bytes_per_pixel = sizeof(Vec3);
  for (Aov a : aovs) {
    switch (a) {
      case Aov::Depth: bytes_per_pixel += sizeof(float); break;
      case Aov::Normal: bytes_per_pixel += sizeof(Vec3); break;
      case Aov::PrimId: bytes_per_pixel += sizeof(uint32_t); break;
      case Aov::Cost: bytes_per_pixel += sizeof(uint32_t); break;
    }
  }
  const uint64_t pixels = static_cast<uint64_t>(w) * static_cast<uint64_t>(h);
  if (pixels * bytes_per_pixel > kMaxFilmBytes)
    throw Error("image size " + std::to_string(w) + "x" + std::to_string(h) + " needs " +
                std::to_string(pixels * bytes_per_pixel >> 20) + " MiB of film (limit " +
                std::to_string(kMaxFilmBytes >> 20) + " MiB)");
}

void render_whitted(const Scene& scene, const Tracer& tracer, const RenderOptions& options, Film& film,
                    RenderStats* stats) {
  const Timer timer;
  const int w = options.width, h = options.height;
  check_image_size(w, h, options.aovs);
  const uint64_t pixels = static_cast<uint64_t>(w) * static_cast<uint64_t>(h);

  const Camera cam = select_camera(scene, options.camera);
  if (scene.indices.size() % 3 != 0) throw Error("render: scene index count is not a multiple of 3");
  // (A branch-free maximum, which the compiler vectorises: this runs for every frame.)
  uint32_t max_index = 0;
  for (uint32_t i : scene.indices) max_index = std::max(max_index, i);
  if (!scene.indices.empty() && max_index >= scene.positions.size())
    throw Error("render: scene has a vertex index out of range");

  film.width = w;
  film.height = h;
  // Every tile writes each of its pixels' colour: the plane is only sized, not cleared, so a
  // film rendered into again (a frame loop, a viewer) costs no 28 MB fill on the calling
  // thread per 1920x1200 frame. The AOV planes are filled as before: not every pixel writes them.
  film.color.resize(pixels);
  film.depth.clear();
  film.normal.clear();
  film.prim_id.clear();
  film.cost.clear();
  Context ctx{scene, tracer, w, h, 0, 0, 0, 0, false, false, false, false, Material{}, film};
  ctx.voxels = dynamic_cast<const VoxelTracer*>(&tracer);
  for (Aov a : options.aovs) {
    switch (a) {
      case Aov::Depth: ctx.want_depth = true; film.depth.assign(pixels, kInf); break;
      case Aov::Normal: ctx.want_normal = true; film.normal.assign(pixels, Vec3{}); break;
      case Aov::PrimId: ctx.want_prim = true; film.prim_id.assign(pixels, kNoHit); break;
      case Aov::Cost: ctx.want_cost = true; film.cost.assign(pixels, 0); break;
    }
  }
  ctx.tile = std::clamp(options.tile_size > 0 ? options.tile_size : 16, 1, 256);
  ctx.tiles_x = (w + ctx.tile - 1) / ctx.tile;
  const int tiles_y = (h + ctx.tile - 1) / ctx.tile;
  ctx.max_reflect = std::clamp(options.max_reflect, 0, kMaxDepthCap);
  ctx.max_refract = std::clamp(options.max_refract, 0, kMaxDepthCap);
  ctx.shadows = options.shadows;
  // Voxel tracers group their batches by direction octant themselves, which for Whitted's
  // wavefronts is the same grouping: no second pass over the rays for them.
  ctx.group_rays = options.group_coherent_rays && ctx.voxels == nullptr;
  ctx.history_order = ctx.group_rays && ctx.max_reflect + ctx.max_refract < 15;
  ctx.vertex_normals = scene.normals.size() == scene.positions.size();
  // Per-render constants of the shading: materials (the fallback last) and lights.
  ctx.shade.reserve(scene.materials.size() + 1);
  for (const Material& m : scene.materials) {
    ctx.shade.push_back(make_shade_material(m, scene.ambient));
    ctx.absorbing.push_back(max_component(m.absorption) > 0.0f ? 1 : 0);
    ctx.any_absorbing = ctx.any_absorbing || ctx.absorbing.back();
    const auto neg = [](float sigma) { return sigma <= 0.0f ? 0.0f : -sigma; };  // -sigma * d is (-sigma) * d
    ctx.neg_absorption.push_back(Vec3{neg(m.absorption.x), neg(m.absorption.y), neg(m.absorption.z)});
  }
  ctx.shade.push_back(make_shade_material(ctx.fallback, scene.ambient));
  for (const Light& light : scene.lights) {
    LightSetup ls;
    ls.type = light.type;
    ls.power = light.color * light.intensity;
    if (max_component(ls.power) <= 0.0f) continue;
    ls.position = light.position;
    if (light.type == LightType::Directional) {
      ls.l = normalize(-light.direction);
      if (ls.l == Vec3{}) continue;
      ctx.lights.push_back(std::move(ls));
      continue;
    }
    const int n = (light.type == LightType::Sphere && light.radius > 0.0f) ? std::clamp(light.samples, 1, 256) : 1;
    ls.point = n == 1 && light.type != LightType::Sphere;
    if (!ls.point) {
      const float golden = kPi * (3.0f - std::sqrt(5.0f));
      ls.inv_n = 1.0f / static_cast<float>(n);
      for (int k = 0; k < n; ++k) {
        ls.rr.push_back(light.radius * std::sqrt((static_cast<float>(k) + 0.5f) * ls.inv_n));
        ls.phase.push_back(static_cast<float>(k) * golden);
      }
    }
    ctx.lights.push_back(std::move(ls));
  }
  for (const LightSetup& ls : ctx.lights) {
    ctx.light_first_sample.push_back(ctx.shadow_per_hit);
    ctx.shadow_per_hit += ls.rr.empty() ? 1 : ls.rr.size();
  }
  ctx.count();

  const SkyEval sky(scene.sky);
  const PinholeCamera camera(cam, w, h);
  const int tiles = ctx.tiles_x * tiles_y;
  std::atomic<uint64_t> primary{0}, secondary{0}, shadow{0};
  tbb::enumerable_thread_specific<Scratch> scratch;

  const int threads = options.threads > 0 ? options.threads : tbb::this_task_arena::max_concurrency();
  tbb::task_arena arena(std::max(1, threads));
  // Tiles are taken one at a time, in order, from a shared counter by every thread of the
  // arena: the threads work on neighbouring tiles (one region of the scene in the caches at a
  // time) and finish together, with no barrier until the frame is done. Progress is reported
  // by the calling thread only (the arena's slot 0), so the callback never runs concurrently
  // with itself.
  std::atomic<int> next_tile{0};
  const int workers = arena.max_concurrency();
  arena.execute([&] {
    tbb::parallel_for(0, workers, [&](int) {
      Scratch& s = scratch.local();
      TileCounters c;
      const bool report = options.progress && tbb::this_task_arena::current_thread_index() == 0;
      for (int t = next_tile.fetch_add(1, std::memory_order_relaxed); t < tiles;
           t = next_tile.fetch_add(1, std::memory_order_relaxed)) {
        render_tile(ctx, sky, s, camera, t, c);
        if (report) options.progress(static_cast<double>(t + 1) / static_cast<double>(tiles));
      }
      primary += c.primary;
      secondary += c.secondary;
      shadow += c.shadow;
    });
  });
  if (options.progress) options.progress(1.0);

  if (stats) {
    stats->primary_rays = primary.load();
    stats->secondary_rays = secondary.load();
    stats->shadow_rays = shadow.load();
    stats->render_ms = timer.ms();
  }
}

}  // namespace specula
