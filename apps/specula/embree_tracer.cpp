// Embree 3 comparison tracer (owner: accel). See embree_tracer.h.
#ifdef SPECULA_HAVE_EMBREE

#include "embree_tracer.h"

#include <embree3/rtcore.h>

#include <cstring>
#include <string>

#include "specula/error.h"
#include "specula/timer.h"

namespace specula::cli {

struct EmbreeTracer::Impl {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;
};

namespace {
void check_device(RTCDevice device, const char* what) {
  const RTCError err = rtcGetDeviceError(device);
  if (err != RTC_ERROR_NONE) throw Error(std::string("embree: ") + what + " failed (error " + std::to_string(static_cast<int>(err)) + ")");
}
}  // namespace

EmbreeTracer::EmbreeTracer(const TriangleInput& input, int threads, double* build_ms) : impl_(std::make_unique<Impl>()) {
  const std::string config = threads > 0 ? "threads=" + std::to_string(threads) : std::string();
  impl_->device = rtcNewDevice(config.c_str());
  if (!impl_->device) throw Error("embree: rtcNewDevice failed");
  impl_->scene = rtcNewScene(impl_->device);
  rtcSetSceneBuildQuality(impl_->scene, RTC_BUILD_QUALITY_MEDIUM);
  const size_t nv = input.positions.size(), nt = input.indices.size() / 3;
  RTCGeometry geom = rtcNewGeometry(impl_->device, RTC_GEOMETRY_TYPE_TRIANGLE);
  rtcSetGeometryBuildQuality(geom, RTC_BUILD_QUALITY_MEDIUM);
  // Embree reads vertex buffers with 16-byte loads: one float of padding at the end.
  auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                         3 * sizeof(float), nv > 0 ? nv : 1));
  auto* ib = static_cast<unsigned*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                            3 * sizeof(unsigned), nt));
  check_device(impl_->device, "geometry buffers");
  for (size_t i = 0; i < nv; ++i) {
    vb[3 * i] = input.positions[i].x;
    vb[3 * i + 1] = input.positions[i].y;
    vb[3 * i + 2] = input.positions[i].z;
  }
  if (nt > 0) std::memcpy(ib, input.indices.data(), nt * 3 * sizeof(unsigned));
  rtcCommitGeometry(geom);
  rtcAttachGeometry(impl_->scene, geom);
  rtcReleaseGeometry(geom);
  const Timer timer;
  rtcCommitScene(impl_->scene);
  if (build_ms) *build_ms = timer.ms();
  check_device(impl_->device, "rtcCommitScene");
}

EmbreeTracer::~EmbreeTracer() {
  if (impl_->scene) rtcReleaseScene(impl_->scene);
  if (impl_->device) rtcReleaseDevice(impl_->device);
}

void EmbreeTracer::intersect(std::span<const Ray> rays, std::span<Hit> hits, TraceStats* stats) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  for (size_t i = 0; i < rays.size(); ++i) {
    const Ray& r = rays[i];
    RTCRayHit rh;
    rh.ray.org_x = r.org.x, rh.ray.org_y = r.org.y, rh.ray.org_z = r.org.z;
    rh.ray.dir_x = r.dir.x, rh.ray.dir_y = r.dir.y, rh.ray.dir_z = r.dir.z;
    rh.ray.tnear = r.tmin;
    rh.ray.tfar = r.tmax;
    rh.ray.time = 0.0f;
    rh.ray.mask = 0xFFFFFFFFu;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(impl_->scene, &ctx, &rh);
    Hit h;
    if (rh.hit.geomID != RTC_INVALID_GEOMETRY_ID) {
      h.t = rh.ray.tfar;
      h.prim = rh.hit.primID;
      h.u = rh.hit.u;
      h.v = rh.hit.v;
      h.ng = normalize(Vec3{rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z});
    }
    hits[i] = h;
  }
  if (stats) stats->rays += rays.size();
}

void EmbreeTracer::transmittance(std::span<const Ray> rays, std::span<Vec3> out, TraceStats* stats) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  for (size_t i = 0; i < rays.size(); ++i) {
    const Ray& r = rays[i];
    RTCRay ray;
    ray.org_x = r.org.x, ray.org_y = r.org.y, ray.org_z = r.org.z;
    ray.dir_x = r.dir.x, ray.dir_y = r.dir.y, ray.dir_z = r.dir.z;
    ray.tnear = r.tmin;
    ray.tfar = r.tmax;
    ray.time = 0.0f;
    ray.mask = 0xFFFFFFFFu;
    ray.id = 0;
    ray.flags = 0;
    rtcOccluded1(impl_->scene, &ctx, &ray);
    out[i] = ray.tfar < 0.0f ? Vec3{} : Vec3{1.0f, 1.0f, 1.0f};
  }
  if (stats) stats->rays += rays.size();
}

}  // namespace specula::cli

#endif  // SPECULA_HAVE_EMBREE
