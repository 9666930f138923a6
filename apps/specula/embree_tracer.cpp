// Embree 3 comparison tracer (owner: accel). See embree_tracer.h.
#ifdef SPECULA_HAVE_EMBREE

#include "embree_tracer.h"

#include <embree3/rtcore.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cstring>
#include <new>
#include <string>
#include <vector>

#include "accel/triangles.h"

#include "specula/bvh.h"
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

EmbreeTracer::EmbreeTracer(const TriangleInput& input, int threads, double* build_ms, bool robust)
    : impl_(std::make_unique<Impl>()) {
  const std::string config = threads > 0 ? "threads=" + std::to_string(threads) : std::string();
  impl_->device = rtcNewDevice(config.c_str());
  if (!impl_->device) throw Error("embree: rtcNewDevice failed");
  impl_->scene = rtcNewScene(impl_->device);
  rtcSetSceneBuildQuality(impl_->scene, RTC_BUILD_QUALITY_MEDIUM);
  if (robust) rtcSetSceneFlags(impl_->scene, RTC_SCENE_FLAG_ROBUST);
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
  // "threads=N" alone does not hold Embree's TBB build to N threads (a "threads=1" build took
  // the two-thread time on two cores): with a count, the build runs in an arena of that size.
  if (threads > 0)
    tbb::task_arena(threads).execute([&] { rtcCommitScene(impl_->scene); });
  else
    rtcCommitScene(impl_->scene);
  if (build_ms) *build_ms = timer.ms();
  check_device(impl_->device, "rtcCommitScene");
}

EmbreeTracer::~EmbreeTracer() {
  if (impl_->scene) rtcReleaseScene(impl_->scene);
  if (impl_->device) rtcReleaseDevice(impl_->device);
}

namespace {
/// Lane k of a 16-ray packet from \p r (or an invalid lane when r is null).
template <class Ray16>
void set_lane(Ray16& p, int* valid, int k, const Ray* r) {
  valid[k] = r ? -1 : 0;
  const Ray fallback;
  const Ray& x = r ? *r : fallback;
  p.org_x[k] = x.org.x, p.org_y[k] = x.org.y, p.org_z[k] = x.org.z;
  p.dir_x[k] = x.dir.x, p.dir_y[k] = x.dir.y, p.dir_z[k] = x.dir.z;
  p.tnear[k] = x.tmin;
  p.tfar[k] = x.tmax;
  p.time[k] = 0.0f;
  p.mask[k] = 0xFFFFFFFFu;
  p.id[k] = 0;
  p.flags[k] = 0;
}
}  // namespace

void EmbreeTracer::intersect(std::span<const Ray> rays, std::span<Hit> hits, TraceStats* stats) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  if (packets_) {
    ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    for (size_t b = 0; b < rays.size(); b += 16) {
      alignas(64) RTCRayHit16 rh;
      alignas(64) int valid[16];
      for (int k = 0; k < 16; ++k) {
        const size_t i = b + static_cast<size_t>(k);
        set_lane(rh.ray, valid, k, i < rays.size() ? &rays[i] : nullptr);
        rh.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
        rh.hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
      }
      rtcIntersect16(valid, impl_->scene, &ctx, &rh);
      for (int k = 0; k < 16 && b + static_cast<size_t>(k) < rays.size(); ++k) {
        Hit h;
        if (rh.hit.geomID[k] != RTC_INVALID_GEOMETRY_ID) {
          h.t = rh.ray.tfar[k];
          h.prim = rh.hit.primID[k];
          h.u = rh.hit.u[k];
          h.v = rh.hit.v[k];
          h.ng = normalize(Vec3{rh.hit.Ng_x[k], rh.hit.Ng_y[k], rh.hit.Ng_z[k]});
        }
        hits[b + static_cast<size_t>(k)] = h;
      }
    }
    if (stats) stats->rays += rays.size();
    return;
  }
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
  if (packets_) {
    ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    for (size_t b = 0; b < rays.size(); b += 16) {
      alignas(64) RTCRay16 ray;
      alignas(64) int valid[16];
      for (int k = 0; k < 16; ++k) {
        const size_t i = b + static_cast<size_t>(k);
        set_lane(ray, valid, k, i < rays.size() ? &rays[i] : nullptr);
      }
      rtcOccluded16(valid, impl_->scene, &ctx, &ray);
      for (int k = 0; k < 16 && b + static_cast<size_t>(k) < rays.size(); ++k)
        out[b + static_cast<size_t>(k)] = ray.tfar[k] < 0.0f ? Vec3{} : Vec3{1.0f, 1.0f, 1.0f};
    }
    if (stats) stats->rays += rays.size();
    return;
  }
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

namespace {
/// One node of the tree rtcBuildBVH hands out through the callbacks below (in its own
/// thread-local memory, freed with the RTCBVH): the children's boxes live in the parent.
struct SahNode {
  bool leaf = false;
  unsigned count = 0;  ///< children (inner node) or triangles (leaf)
  SahNode* child[2] = {nullptr, nullptr};
  RTCBounds box[2] = {};
};

void* sah_create_node(RTCThreadLocalAllocator alloc, unsigned int child_count, void*) {
  void* p = rtcThreadLocalAlloc(alloc, sizeof(SahNode), alignof(SahNode));
  auto* n = new (p) SahNode;
  n->count = child_count;
  return n;
}
void sah_set_children(void* node, void** children, unsigned int count, void*) {
  auto* n = static_cast<SahNode*>(node);
  for (unsigned i = 0; i < count && i < 2; ++i) n->child[i] = static_cast<SahNode*>(children[i]);
}
void sah_set_bounds(void* node, const RTCBounds** bounds, unsigned int count, void*) {
  auto* n = static_cast<SahNode*>(node);
  for (unsigned i = 0; i < count && i < 2; ++i) n->box[i] = *bounds[i];
}
void* sah_create_leaf(RTCThreadLocalAllocator alloc, const RTCBuildPrimitive*, size_t count, void*) {
  void* p = rtcThreadLocalAlloc(alloc, sizeof(SahNode), alignof(SahNode));
  auto* n = new (p) SahNode;
  n->leaf = true;
  n->count = static_cast<unsigned>(count);
  return n;
}

}  // namespace

EmbreeSahTree embree_binary_sah(const TriangleInput& input, int max_leaf, float traversal_cost) {
  EmbreeSahTree out;
  out.max_leaf = std::clamp(max_leaf, 1, static_cast<int>(RTC_BUILD_MAX_PRIMITIVES_PER_LEAF));
  std::vector<RTCBuildPrimitive> prims;
  const size_t nt = input.indices.size() / 3;
  prims.reserve(nt);
  RTCBounds root{kInf, kInf, kInf, 0.0f, -kInf, -kInf, -kInf, 0.0f};
  for (size_t t = 0; t < nt; ++t) {
    const Vec3& a = input.positions[input.indices[3 * t]];
    const Vec3& b = input.positions[input.indices[3 * t + 1]];
    const Vec3& c = input.positions[input.indices[3 * t + 2]];
    if (accel::is_degenerate(a, b, c)) continue;
    const Vec3 lo = min(min(a, b), c), hi = max(max(a, b), c);
    RTCBuildPrimitive p;
    p.lower_x = lo.x, p.lower_y = lo.y, p.lower_z = lo.z, p.geomID = 0;
    p.upper_x = hi.x, p.upper_y = hi.y, p.upper_z = hi.z, p.primID = static_cast<unsigned>(t);
    prims.push_back(p);
    root.lower_x = std::min(root.lower_x, lo.x), root.lower_y = std::min(root.lower_y, lo.y);
    root.lower_z = std::min(root.lower_z, lo.z), root.upper_x = std::max(root.upper_x, hi.x);
    root.upper_y = std::max(root.upper_y, hi.y), root.upper_z = std::max(root.upper_z, hi.z);
  }
  if (prims.empty()) return out;
  RTCDevice device = rtcNewDevice("threads=1");
  if (!device) throw Error("embree: rtcNewDevice failed");
  RTCBVH bvh = rtcNewBVH(device);
  RTCBuildArguments args = rtcDefaultBuildArguments();
  args.buildQuality = RTC_BUILD_QUALITY_MEDIUM;
  args.maxBranchingFactor = 2;
  args.maxDepth = 64;
  args.sahBlockSize = 4;  // leaves cost per block of four triangles, as in our builder
  args.minLeafSize = 1;
  args.maxLeafSize = static_cast<unsigned>(out.max_leaf);
  args.traversalCost = traversal_cost;
  args.intersectionCost = 1.0f;
  args.bvh = bvh;
  args.primitives = prims.data();
  args.primitiveCount = prims.size();
  args.primitiveArrayCapacity = prims.size();
  args.createNode = sah_create_node;
  args.setNodeChildren = sah_set_children;
  args.setNodeBounds = sah_set_bounds;
  args.createLeaf = sah_create_leaf;
  const Timer timer;
  void* top = nullptr;
  tbb::task_arena(1).execute([&] { top = rtcBuildBVH(&args); });
  out.build_ms = timer.ms();
  const RTCError err = rtcGetDeviceError(device);
  if (err != RTC_ERROR_NONE || !top) {
    rtcReleaseBVH(bvh);
    rtcReleaseDevice(device);
    throw Error("embree: rtcBuildBVH failed (error " + std::to_string(static_cast<int>(err)) + ")");
  }
  // The tree as BvhNodes (node 0 the root, node 1 padding, as Bvh::nodes()), scored by the very
  // function that gives BuildInfo::sah_cost. Every node's box is in its parent; the root's is
  // the triangles' bounds.
  const auto node_of = [](const RTCBounds& b, const SahNode* n) {
    BvhNode node;
    node.min = {b.lower_x, b.lower_y, b.lower_z};
    node.max = {b.upper_x, b.upper_y, b.upper_z};
    node.count = n->leaf ? n->count : 0;
    return node;
  };
  struct Item {
    const SahNode* node;
    uint32_t depth;
  };
  const auto* const root_node = static_cast<const SahNode*>(top);
  std::vector<BvhNode> nodes{node_of(root, root_node), BvhNode{}};
  std::vector<Item> stack{{root_node, 0}};
  while (!stack.empty()) {
    const Item it = stack.back();
    stack.pop_back();
    out.depth = std::max(out.depth, it.depth);
    if (it.node->leaf) continue;
    for (unsigned i = 0; i < it.node->count && i < 2; ++i) {
      nodes.push_back(node_of(it.node->box[i], it.node->child[i]));
      stack.push_back({it.node->child[i], it.depth + 1});
    }
  }
  out.nodes = nodes.size() - 1;  // without the padding
  out.leaves = static_cast<size_t>(std::count_if(nodes.begin(), nodes.end(), [](const BvhNode& n) { return n.is_leaf(); }));
  out.sah_cost = binary_sah_cost(nodes, traversal_cost);
  rtcReleaseBVH(bvh);
  rtcReleaseDevice(device);
  return out;
}

}  // namespace specula::cli

#endif  // SPECULA_HAVE_EMBREE
