// Dielectric Fresnel reflectance and Snell refraction (owner: render). The bodies are inline in
// render/fresnel.h, where the integrator calls them per hit.
#include "render/fresnel.h"

#include "specula/render.h"

namespace specula {

float fresnel_dielectric(float cos_i, float eta) { return detail::fresnel_dielectric(cos_i, eta); }

bool refract(const Vec3& d, const Vec3& n, float eta, Vec3& out) { return detail::refract(d, n, eta, out); }

}  // namespace specula
