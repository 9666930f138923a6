// Placeholder until the integrator and image I/O land; owner: render. Delete when implementing.
#include "specula/error.h"
#include "specula/image.h"
#include "specula/render.h"

namespace specula {
std::vector<Aov> parse_aovs(const std::string&) { return {}; }
const char* aov_name(Aov) { return "?"; }
PinholeCamera::PinholeCamera(const Camera&, int, int) {}
Ray PinholeCamera::generate(float, float) const { return {}; }
std::vector<Vec3> shadow_transmittance(const Scene&) { return {}; }
Film render_whitted(const Scene&, const Tracer&, const RenderOptions&, RenderStats*) { throw Error("render: not implemented"); }
float fresnel_dielectric(float, float) { return 0; }
bool refract(const Vec3&, const Vec3&, float, Vec3&) { return false; }
void write_file_atomic(const std::string&, std::span<const uint8_t>) { throw Error("not implemented"); }
void write_png(const std::string&, int, int, std::span<const Vec3>, Tonemap) { throw Error("not implemented"); }
void write_exr(const std::string&, int, int, std::span<const Vec3>) { throw Error("not implemented"); }
void write_image(const std::string&, int, int, std::span<const Vec3>, Tonemap) { throw Error("not implemented"); }
std::vector<Vec3> read_image(const std::string&, int&, int&) { throw Error("not implemented"); }
void load_sky_image(Sky&) {}
std::vector<std::string> write_aovs(const std::string&, const Film&) { return {}; }
}  // namespace specula
