/// \file render.h
/// Cameras, film and the Whitted integrator. Integrators see a Tracer, never a structure.
#pragma once

#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "specula/math.h"
#include "specula/ray.h"
#include "specula/scene.h"
#include "specula/tracer.h"

namespace specula {

enum class Aov : uint8_t { Depth, Normal, PrimId, Cost };

/// Parses "depth,normal,prim,cost" (also "primid", "prim_id"); throws specula::Error otherwise.
std::vector<Aov> parse_aovs(const std::string& list);
const char* aov_name(Aov aov);

/// Linear float RGB film plus optional AOV planes (same size as color when requested).
struct Film {
  int width = 0, height = 0;
  std::vector<Vec3> color;
  std::vector<float> depth;       ///< primary hit distance, +inf on a miss
  std::vector<Vec3> normal;       ///< primary shading normal, (0,0,0) on a miss
  std::vector<uint32_t> prim_id;  ///< primary triangle index, kNoHit on a miss
  std::vector<uint32_t> cost;     ///< BVH nodes visited by all rays of the pixel
};

struct RenderOptions {
  int width = 640;
  int height = 480;
  std::string camera;        ///< camera name; empty = the scene's first camera
  int max_reflect = 4;       ///< max mirror bounces on a path (seed 001's d_min/d_max)
  int max_refract = 6;       ///< max refraction events on a path
  int threads = 0;           ///< 0 = all hardware threads
  /// false: lights shade every hit as if unoccluded, no shadow rays are traced (seed 000's
  /// "Whitted ray tracer without shadow rays"); reflections and refractions are unchanged.
  bool shadows = true;
  int tile_size = 16;
  /// Hand the tracer each wavefront and shadow batch grouped by bounce history (and light), so
  /// coherent rays sit side by side where a triangle tracer takes them as packets. The image is
  /// the same bit for bit either way; false only to measure or test that.
  bool group_coherent_rays = true;
  std::vector<Aov> aovs;
  /// Called now and then with the fraction done, always from the thread that called render.
  std::function<void(double)> progress;
};

struct RenderStats {
  double render_ms = 0.0;
  uint64_t primary_rays = 0;
  uint64_t secondary_rays = 0;  ///< reflection + refraction
  uint64_t shadow_rays = 0;
  uint64_t total_rays() const { return primary_rays + secondary_rays + shadow_rays; }
};

/// Pinhole camera generating primary rays through pixel centres.
class PinholeCamera {
 public:
  PinholeCamera(const Camera& cam, int width, int height);
  /// Ray through image position (px, py) in pixels, (0,0) = top-left corner; the direction
  /// is unit length, so hit distances are in scene units.
  Ray generate(float px, float py) const { return ray_from_column(column(px), py); }
  /// The half of generate()'s direction sum that depends on the column only; the integrator
  /// computes it once per column of a tile. ray_from_column(column(px), py) is generate(px, py)
  /// bit for bit: the same sum, (top_left + du px) + dv py, in the same order.
  Vec3 column(float px) const { return top_left_ + du_ * px; }
  Ray ray_from_column(const Vec3& col, float py) const { return Ray{origin_, 0.0f, normalize(col + dv_ * py), kInf}; }

 private:
  Vec3 origin_, top_left_, du_, dv_;
};

/// Per-triangle shadow transmittance derived from the materials (transparency * (1 - F0-ish)
/// tint): what the Tracer is built with so shadow rays can pass through glass and water.
std::vector<Vec3> shadow_transmittance(const Scene& scene);

/// Throws specula::Error when render_whitted() would refuse this image size: a side outside
/// 1..32768, or film planes (colour and \p aovs) over 2 GiB. Front ends call it before they load
/// a scene, so an absurd size fails at once, not after the load and the build.
void check_image_size(int width, int height, std::span<const Aov> aovs = {});

/// The camera \p name names in \p scene (RenderOptions::camera): the scene's first camera when
/// \p name is empty. Throws specula::Error when there is no such camera, listing the ones there
/// are. Front ends call it once the scene is loaded, before they build its tracer.
const Camera& select_camera(const Scene& scene, const std::string& name);

/// Renders the scene with the iterative Whitted integrator. Bit-identical for any thread
/// count. Throws specula::Error for an unknown camera (select_camera) or an absurd image size
/// (check_image_size).
Film render_whitted(const Scene& scene, const Tracer& tracer, const RenderOptions& options,
                    RenderStats* stats = nullptr);

/// The same image rendered into \p film, whose planes' storage is reused when they already have
/// the right size: a frame loop or a viewer renders every frame into one film, with no
/// allocation, fill or page faults per frame. Planes of AOVs not requested are emptied. The
/// film is left unspecified when this throws.
void render_whitted(const Scene& scene, const Tracer& tracer, const RenderOptions& options, Film& film,
                    RenderStats* stats = nullptr);

/// Dielectric Fresnel reflectance for unpolarised light (exact formula). cos_i is the cosine
/// of the incident angle (>= 0), eta = n_incident / n_transmitted. Returns 1 on total
/// internal reflection.
float fresnel_dielectric(float cos_i, float eta);

/// Refracts unit direction \p d through the surface with unit normal \p n facing against d
/// (dot(d, n) < 0), eta = n_incident / n_transmitted. Returns false on total internal
/// reflection.
bool refract(const Vec3& d, const Vec3& n, float eta, Vec3& out);

}  // namespace specula
