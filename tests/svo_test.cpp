// Sparse voxel octree tests: traversal == grid DDA == brute force over the voxel list (cubes
// and contours, bit-identical t and normals), rays from outside / inside / inside voxels,
// axis-parallel with +-0, lattice-grazing rays, NaN rays, level of detail, transmittance,
// memory. Owner: voxel tracers.
#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "specula/error.h"
#include "specula/load.h"
#include "specula/render.h"
#include "specula/svo.h"
#include "specula/voxel_grid.h"
#include "specula/voxel_scene.h"
#include "specula/voxel_tracer.h"
#include "voxel/voxel_brute.h"
#include "ray_test_util.h"

namespace specula {
namespace {

using test::make_ray;
using test::describe;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

/// A grid whose local frame is an exact power-of-two scaling of world space (lattice rays are
/// exact), and a generic one.
VoxelGrid dyadic_grid(int depth) { return VoxelGrid{Vec3{-1.0f, -1.0f, -1.0f}, 2.0f, depth}; }
VoxelGrid generic_grid(int depth) { return VoxelGrid{Vec3{0.37f, -1.3f, 2.1f}, 3.7f, depth}; }

VoxelAttributes random_attrs(std::mt19937& rng, float voxel_size) {
  std::uniform_real_distribution<float> u(-1.0f, 1.0f), u01(0.0f, 1.0f);
  VoxelAttributes a;
  Vec3 n;
  do n = Vec3(u(rng), u(rng), u(rng));
  while (length(n) < 0.1f || length(n) > 1.0f);
  if (u01(rng) < 0.2f) n = Vec3(0.0f, 0.0f, 0.0f), n[static_cast<int>(rng() % 3)] = u(rng) < 0 ? -1.0f : 1.0f;
  a.normal = normalize(n);
  a.colour = Vec3(u01(rng), u01(rng), u01(rng));
  a.reflectivity = u01(rng);
  a.transparency = u01(rng) < 0.5f ? 0.0f : u01(rng);
  a.ior = 1.0f + u01(rng);
  const float c = 0.6f * voxel_size * u(rng), w = 0.3f * voxel_size * u01(rng);
  a.contour_lo = c - w;
  a.contour_hi = u01(rng) < 0.2f ? c - w : c + w;  // some flat (zero thickness) slabs
  a.material = static_cast<uint32_t>(rng() % 7);
  return a;
}

VoxelSet random_set(const VoxelGrid& grid, size_t count, uint32_t seed, bool attrs = true) {
  std::mt19937 rng(seed);
  const uint64_t cells = uint64_t{1} << (3 * grid.depth);
  VoxelSet set;
  set.grid = grid;
  std::vector<uint64_t> codes;
  for (size_t i = 0; i < count; ++i) codes.push_back((static_cast<uint64_t>(rng()) << 32 | rng()) % cells);
  std::sort(codes.begin(), codes.end());
  codes.erase(std::unique(codes.begin(), codes.end()), codes.end());
  set.codes = codes;
  if (attrs)
    for (size_t i = 0; i < codes.size(); ++i) set.attrs.push_back(random_attrs(rng, grid.voxel_size()));
  return set;
}

/// All voxels of the box [lo, hi] (voxel coordinates, inclusive).
VoxelSet block_set(const VoxelGrid& grid, uint32_t lo, uint32_t hi, uint32_t seed) {
  std::mt19937 rng(seed);
  VoxelSet set;
  set.grid = grid;
  for (uint32_t z = lo; z <= hi; ++z)
    for (uint32_t y = lo; y <= hi; ++y)
      for (uint32_t x = lo; x <= hi; ++x) set.codes.push_back(morton_encode(x, y, z));
  std::sort(set.codes.begin(), set.codes.end());
  for (size_t i = 0; i < set.codes.size(); ++i) set.attrs.push_back(random_attrs(rng, grid.voxel_size()));
  return set;
}

/// Ray families: from outside, from inside the root, from inside occupied voxels, axis
/// parallel with +-0 components (origins on lattice planes too), lattice-to-lattice rays
/// (through edges and corners), random [tmin, tmax] windows, and a few NaN / degenerate rays.
std::vector<Ray> make_rays(const VoxelSet& set, size_t count, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f), u01(0.0f, 1.0f);
  const VoxelGrid& g = set.grid;
  const float s = g.voxel_size();
  const uint32_t res = g.resolution();
  const Vec3 centre = g.origin + Vec3(0.5f * g.side);
  const auto in_box = [&](float margin) {
    return g.origin + Vec3(u01(rng), u01(rng), u01(rng)) * (g.side * (1.0f + 2.0f * margin)) - Vec3(margin * g.side);
  };
  const auto rand_dir = [&] {
    Vec3 d;
    do d = Vec3(u(rng), u(rng), u(rng));
    while (length(d) < 0.05f);
    return d * (0.25f + 4.0f * u01(rng));  // not unit: t is in units of |dir|
  };
  const auto lattice = [&](int lo, int hi) {
    std::uniform_int_distribution<int> li(lo, hi);
    return g.origin + Vec3(static_cast<float>(li(rng)), static_cast<float>(li(rng)), static_cast<float>(li(rng))) * s;
  };
  const auto zero = [&] { return (rng() & 1) ? 0.0f : -0.0f; };
  std::vector<Ray> rays;
  rays.reserve(count);
  const int ires = static_cast<int>(res);
  while (rays.size() < count) {
    const uint32_t kind = static_cast<uint32_t>(rng() % 10);
    Ray r;
    switch (kind) {
      case 0:
      case 1: {  // from outside towards the box
        Vec3 org = centre + normalize(rand_dir()) * (g.side * (1.0f + 2.0f * u01(rng)));
        r = make_ray(org, in_box(0.1f) - org);
        break;
      }
      case 2:  // inside the root
        r = make_ray(in_box(0.0f), rand_dir());
        break;
      case 3: {  // inside an occupied voxel
        if (set.codes.empty()) continue;
        uint32_t x, y, z;
        morton_decode(set.codes[rng() % set.codes.size()], x, y, z);
        const Vec3 lo = g.voxel_box(x, y, z).min;
        r = make_ray(lo + Vec3(u01(rng), u01(rng), u01(rng)) * s, rand_dir());
        break;
      }
      case 4: {  // axis parallel, one or two +-0 components, origin often on lattice planes
        Vec3 d = rand_dir();
        const int a0 = static_cast<int>(rng() % 3);
        d[a0] = zero();
        if (rng() & 1) d[(a0 + 1 + static_cast<int>(rng() % 2)) % 3] = zero();
        Vec3 org = in_box(0.2f);
        if (rng() & 1) {
          const Vec3 l = lattice(-1, ires + 1);
          for (int i = 0; i < 3; ++i)
            if (d[i] == 0.0f && (rng() % 4) != 0) org[i] = l[i];
        }
        r = make_ray(org, d);
        break;
      }
      case 5:
      case 6: {  // lattice to lattice: through edges and corners
        const Vec3 a = lattice(-2, ires + 2), b = lattice(0, ires);
        if (a == b) continue;
        r = make_ray(a, b - a);
        break;
      }
      case 7: {  // lattice origin, axis-diagonal direction
        const Vec3 a = lattice(-1, ires + 1);
        Vec3 d;
        for (int i = 0; i < 3; ++i) d[i] = static_cast<float>(static_cast<int>(rng() % 3) - 1) * (0.5f + u01(rng));
        if (d == Vec3{}) continue;
        r = make_ray(a, d);
        break;
      }
      case 8: {  // windows
        Vec3 org = centre + normalize(rand_dir()) * (g.side * 1.5f);
        r = make_ray(org, in_box(0.0f) - org, u01(rng) * 1.5f, 0.5f + u01(rng) * 1.5f);
        if (rng() % 8 == 0) r.tmax = r.tmin;
        break;
      }
      default: {  // degenerate
        const uint32_t which = static_cast<uint32_t>(rng() % 16);
        r = make_ray(in_box(0.2f), rand_dir());
        if (which == 0) r.org.x = kNaN;
        else if (which == 1) r.dir.y = kNaN;
        else if (which == 2) r.dir = Vec3{};
        else if (which == 3) r.tmin = kNaN;
        else if (which == 4) r.tmax = -1.0f;
        else if (which == 5) r.org.z = kInf;
        else if (which == 6) r.dir = Vec3(zero(), zero(), zero());
        break;
      }
    }
    rays.push_back(r);
  }
  return rays;
}

std::string describe(const Hit& h) {
  std::ostringstream os;
  os.precision(9);
  if (!h.hit()) return "miss";
  os << "prim " << h.prim << " t " << h.t << " n (" << h.ng.x << ", " << h.ng.y << ", " << h.ng.z << ")";
  return os.str();
}

bool same_hit(const Hit& a, const Hit& b) {
  if (a.prim != b.prim) return false;
  if (!a.hit()) return true;
  return std::bit_cast<uint32_t>(a.t) == std::bit_cast<uint32_t>(b.t) && a.ng == b.ng;
}

/// Counts rays where \p b differs from \p a (printing the first few).
size_t compare_hits(const Tracer& a, const Tracer& b, std::span<const Ray> rays, const std::string& what) {
  std::vector<Hit> ha(rays.size(), test::unwritten_hit(0xFFFFFFF0u)), hb(rays.size(), test::unwritten_hit(0xFFFFFFF1u));
  a.intersect(rays, ha);
  b.intersect(rays, hb);
  size_t bad = 0;
  for (size_t i = 0; i < rays.size(); ++i) {
    if (same_hit(ha[i], hb[i])) continue;
    if (++bad <= 5)
      ADD_FAILURE() << what << ": " << a.name() << " " << describe(ha[i]) << " vs " << b.name() << " " << describe(hb[i])
                    << " for ray " << describe(rays[i]);
  }
  return bad;
}

size_t compare_transmittance(const Tracer& a, const Tracer& b, std::span<const Ray> rays, const std::string& what) {
  std::vector<Vec3> ta(rays.size(), Vec3(-1.0f)), tb(rays.size(), Vec3(-2.0f));  // unwritten: a difference
  a.transmittance(rays, ta);
  b.transmittance(rays, tb);
  size_t bad = 0;
  for (size_t i = 0; i < rays.size(); ++i) {
    if (ta[i] == tb[i]) continue;
    if (++bad <= 5)
      ADD_FAILURE() << what << ": transmittance " << a.name() << " " << ta[i].x << " vs " << b.name() << " " << tb[i].x
                    << " for ray " << describe(rays[i]);
  }
  return bad;
}

struct Case {
  std::string name;
  VoxelSet set;
};

std::vector<Case> oracle_cases() {
  std::vector<Case> cases;
  cases.push_back({"random sparse d5", random_set(dyadic_grid(5), 400, 1)});
  cases.push_back({"random dense d3 generic", random_set(generic_grid(3), 300, 2)});
  cases.push_back({"shell d5", make_sphere_shell_set(dyadic_grid(5), Vec3(0.05f, -0.1f, 0.0f), 0.8f, 3)});
  cases.push_back({"block d3", block_set(dyadic_grid(3), 2, 5, 3)});
  cases.push_back({"single d7", random_set(dyadic_grid(7), 1, 4)});
  cases.push_back({"random d4 no attrs", random_set(generic_grid(4), 200, 5, false)});
  cases.push_back({"full d2", block_set(generic_grid(2), 0, 3, 6)});
  cases.push_back({"empty d4", random_set(dyadic_grid(4), 0, 7)});
  return cases;
}

TEST(SvoOracle, SvoGridAndBruteForceAgreeBitForBit) {
  for (const Case& c : oracle_cases()) {
    for (const VoxelHitMode mode : {VoxelHitMode::Cubes, VoxelHitMode::Contours}) {
      VoxelTracerOptions o;
      o.mode = mode;
      const SparseVoxelOctree svo = SparseVoxelOctree::build(c.set, o);
      const VoxelGridTracer grid = VoxelGridTracer::build(c.set, o);
      const voxel::VoxelBruteTracer brute(c.set, o);
      const size_t n = c.set.size() > 1000 ? 5000 : 20000;
      const std::vector<Ray> rays = make_rays(c.set, n, 11);
      const std::string what = c.name + " " + to_string(mode);
      EXPECT_EQ(compare_hits(brute, svo, rays, what), 0u) << what;
      EXPECT_EQ(compare_hits(brute, grid, rays, what), 0u) << what;
      // The tests must be able to fail: some rays hit, some miss.
      std::vector<Hit> hits(rays.size());
      svo.intersect(rays, hits);
      const size_t hit_count = static_cast<size_t>(std::count_if(hits.begin(), hits.end(), [](const Hit& h) { return h.hit(); }));
      if (!c.set.codes.empty()) {
        EXPECT_GT(hit_count, rays.size() / 50) << what;
      }
      EXPECT_LT(hit_count, rays.size()) << what;
    }
  }
}

TEST(SvoOracle, HundredThousandRaysSvoEqualsGrid) {
  const std::vector<Case> cases = {
      {"shell d8", make_sphere_shell_set(dyadic_grid(8), Vec3(0.0f), 0.9f)},
      {"random d9", random_set(generic_grid(9), 20000, 21)},
  };
  for (const Case& c : cases) {
    for (const VoxelHitMode mode : {VoxelHitMode::Cubes, VoxelHitMode::Contours}) {
      VoxelTracerOptions o;
      o.mode = mode;
      const SparseVoxelOctree svo = SparseVoxelOctree::build(c.set, o);
      const VoxelGridTracer grid = VoxelGridTracer::build(c.set, o);
      const std::vector<Ray> rays = make_rays(c.set, 100000, 12);
      const std::string what = c.name + " " + to_string(mode);
      EXPECT_EQ(compare_hits(grid, svo, rays, what), 0u) << what;
      // Brute force on a subset (it is O(voxels) per ray).
      const voxel::VoxelBruteTracer brute(c.set, o);
      EXPECT_EQ(compare_hits(brute, svo, std::span<const Ray>(rays).first(400), what), 0u) << what;
    }
  }
}

TEST(SvoOracle, DeepTreesAgreeWithBruteForce) {
  for (const int depth : {12, 16, 21}) {
    VoxelSet set = random_set(dyadic_grid(depth), 60, 30 + static_cast<uint32_t>(depth));
    // Plus a little cluster so neighbouring voxels exist at full depth.
    const uint32_t base = 1u << (depth - 1);
    for (uint32_t i = 0; i < 3; ++i) set.codes.push_back(morton_encode(base + i, base, base));
    std::sort(set.codes.begin(), set.codes.end());
    set.codes.erase(std::unique(set.codes.begin(), set.codes.end()), set.codes.end());
    std::mt19937 rng(5);
    set.attrs.clear();
    for (size_t i = 0; i < set.codes.size(); ++i) set.attrs.push_back(random_attrs(rng, set.grid.voxel_size()));
    const voxel::VoxelBruteTracer brute(set);
    const SparseVoxelOctree svo = SparseVoxelOctree::build(set);
    // Rays aimed at the voxels (random rays would almost never hit at this depth).
    std::vector<Ray> rays;
    std::uniform_real_distribution<float> u(-1.0f, 1.0f), u01(0.0f, 1.0f);
    for (int i = 0; i < 3000; ++i) {
      uint32_t x, y, z;
      morton_decode(set.codes[rng() % set.codes.size()], x, y, z);
      const Vec3 target = set.grid.voxel_box(x, y, z).min + Vec3(u01(rng), u01(rng), u01(rng)) * set.grid.voxel_size();
      Vec3 org = target + normalize(Vec3(u(rng), u(rng), u(rng))) * (u01(rng) * 3.0f);
      if (i % 5 == 0) org = target + Vec3(u(rng), 0, 0) * set.grid.voxel_size() * 4.0f;  // nearly along an axis
      rays.push_back(make_ray(org, target - org));
    }
    EXPECT_EQ(compare_hits(brute, svo, rays, "depth " + std::to_string(depth)), 0u);
    std::vector<Hit> hits(rays.size());
    svo.intersect(rays, hits);
    EXPECT_GT(std::count_if(hits.begin(), hits.end(), [](const Hit& h) { return h.hit(); }), 1000);
  }
}

/// Coherent bundles, as the integrator traces them: camera rays in 16 x 16 tiles from eyes
/// outside, on the boundary and inside the grid (inside occupied voxels too), parallel
/// "sun" rays from a lattice of origins (some on voxel planes) with +-0 components, rays
/// with tmin / tmax windows, and the rays of make_rays() shuffled in between so packets mix
/// octants, fixed axes and invalid rays.
std::vector<Ray> coherent_rays(const VoxelSet& set, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f), u01(0.0f, 1.0f);
  const VoxelGrid& g = set.grid;
  const Vec3 centre = g.origin + Vec3(0.5f * g.side);
  std::vector<Ray> rays;
  const auto camera = [&](Vec3 eye, Vec3 target, float fov, int w, int h, float tmin, float tmax) {
    Vec3 fwd = normalize(target - eye), right = cross(fwd, Vec3(0.0f, 1.0f, 0.0f));
    if (length(right) < 1e-3f) right = Vec3(1.0f, 0.0f, 0.0f);
    right = normalize(right);
    const Vec3 up = cross(right, fwd);
    for (int ty = 0; ty < h; ty += 16)
      for (int tx = 0; tx < w; tx += 16)
        for (int y = ty; y < std::min(ty + 16, h); ++y)
          for (int x = tx; x < std::min(tx + 16, w); ++x) {
            const float px = (2.0f * (static_cast<float>(x) + 0.5f) / static_cast<float>(w) - 1.0f) * fov;
            const float py = (1.0f - 2.0f * (static_cast<float>(y) + 0.5f) / static_cast<float>(h)) * fov;
            rays.push_back(make_ray(eye, fwd + right * px + up * py, tmin, tmax));
          }
  };
  camera(centre + Vec3(0.3f, 0.5f, 1.6f) * g.side, centre, 0.5f, 48, 32, 0.0f, kInf);
  camera(centre + Vec3(-1.2f, -0.2f, -0.4f) * g.side, centre + Vec3(0.1f) * g.side, 0.8f, 32, 32, 0.0f, kInf);
  camera(centre + Vec3(0.05f, -0.1f, 0.02f) * g.side, centre + Vec3(1.0f, 0.3f, 0.2f) * g.side, 1.2f, 32, 32, 0.0f, kInf);
  camera(g.origin, centre, 0.3f, 16, 16, 0.0f, kInf);  // eye on the root's corner
  camera(centre + Vec3(0.2f, 0.9f, -0.3f) * g.side, centre, 0.6f, 32, 16, 0.3f * g.side, 1.2f * g.side);
  for (int k = 0; k < 4 && !set.codes.empty(); ++k) {  // eyes inside occupied voxels
    uint32_t x, y, z;
    morton_decode(set.codes[rng() % set.codes.size()], x, y, z);
    const Vec3 eye = g.voxel_box(x, y, z).min + Vec3(u01(rng), u01(rng), u01(rng)) * g.voxel_size();
    camera(eye, eye + Vec3(u(rng), u(rng), u(rng)), 0.7f, 16, 16, 0.0f, kInf);
  }
  // Parallel bundles from lattice origins, with zero components of either sign.
  const float s = g.voxel_size();
  const int res = static_cast<int>(g.resolution());
  for (const Vec3 dir : {Vec3(0.45f, 1.0f, 0.35f), Vec3(1.0f, 0.0f, -0.0f), Vec3(-0.0f, -1.0f, 0.0f), Vec3(0.3f, -0.0f, -0.8f)}) {
    for (int k = 0; k < 256; ++k) {
      Vec3 org = g.origin + Vec3(u01(rng), u01(rng), u01(rng)) * g.side;
      if (k % 2 == 0)
        for (int i = 0; i < 3; ++i)
          if (dir[i] == 0.0f) org[i] = g.origin[i] + static_cast<float>(static_cast<int>(rng() % static_cast<uint32_t>(res + 1))) * s;
      rays.push_back(make_ray(org - dir * g.side, dir));
    }
  }
  // Incoherent rays mixed in.
  std::vector<Ray> mixed = make_rays(set, 3000, seed + 1);
  for (size_t i = 0; i < mixed.size(); ++i) rays.insert(rays.begin() + static_cast<std::ptrdiff_t>((i * 7919) % rays.size()), mixed[i]);
  return rays;
}

// The batch form of make_local_ray (grid constants computed once) gives the same rays bit for
// bit, and the same verdict, as the reference one, degenerate rays included.
TEST(SvoPacket, BatchLocalRaysEqualTheKernelsOwn) {
  for (const VoxelGrid& g : {dyadic_grid(7), generic_grid(9), VoxelGrid{Vec3(1e30f, -1e30f, 0.0f), 1e-3f, 12}}) {
    VoxelSet set;
    set.grid = g;
    const voxel::LocalFrame frame(g);
    std::vector<Ray> rays = make_rays(set, 20000, 51);
    rays.push_back(make_ray(Vec3(0, 0, 0), Vec3(1e-40f, -1e-45f, 1.0f)));  // 1/d not finite
    rays.push_back(make_ray(Vec3(3e38f, 0, 0), Vec3(1, 0, 0)));             // local origin overflows
    rays.push_back(make_ray(Vec3(0, 0, 0), Vec3(3e38f, 1, 0)));             // local direction overflows
    rays.push_back(make_ray(Vec3(0, 0, 0), Vec3(1, 0, 0), -kInf, kInf));
    size_t accepted = 0;
    for (const Ray& ray : rays) {
      voxel::LocalRay a{}, b{};
      const bool ok_a = voxel::make_local_ray(ray, g, a), ok_b = voxel::make_local_ray(ray, frame, b);
      ASSERT_EQ(ok_a, ok_b) << describe(ray);
      if (!ok_a) continue;
      ++accepted;
      ASSERT_EQ(std::memcmp(&a, &b, sizeof a), 0) << describe(ray);
    }
    EXPECT_GT(accepted, rays.size() / 2);
  }
}

/// Limits the packet kernel (width, AVX-512 or not) for its scope.
struct PacketWidth {
  explicit PacketWidth(int w, bool avx512 = true) { voxel::set_svo_packet_width_limit(w, avx512); }
  ~PacketWidth() { voxel::set_svo_packet_width_limit(32, true); }
};

/// Every packet kernel (AVX-512 32 and 16 lanes, AVX2 16 and 8 lanes) and the single-ray path.
struct Kernel {
  int width;
  bool avx512;
  /// Whether this CPU runs it (the limit then selects exactly it).
  bool runs() const {
    const PacketWidth limit(width, avx512);
    const voxel::SvoPacketKernel k = voxel::svo_packet_kernel();
    return k.width == width && k.avx512 == avx512;
  }
  std::string name() const { return std::to_string(width) + (width == 1 ? "" : avx512 ? " avx512" : " avx2"); }
};
constexpr Kernel kKernels[] = {{32, true}, {16, true}, {16, false}, {8, false}, {1, false}};

// The packet kernels (32 and 16 lanes with AVX-512, 16 and 8 with AVX2) and the single-ray traversal give
// bit-identical hits and transmittance to the brute force (the grid for the largest set), batch by batch and ray by ray,
// in both hit modes, with and without level of detail and material skipping.
TEST(SvoPacket, EveryKernelEqualsBruteForceOnCoherentBundles) {
  const std::vector<Case> cases = {
      {"shell d7", make_sphere_shell_set(dyadic_grid(7), Vec3(0.05f, -0.1f, 0.0f), 0.8f, 5)},
      {"random d6 generic", random_set(generic_grid(6), 4000, 41)},
      {"block d4", block_set(dyadic_grid(4), 3, 12, 42)},
  };
  const voxel::SvoPacketKernel cpu = voxel::svo_packet_kernel();
  std::printf("[ info     ] packet width on this CPU: %d (%s)\n", cpu.width, cpu.avx512 ? "avx512" : "avx2 or none");
  for (const Case& c : cases) {
    const std::vector<Ray> rays = coherent_rays(c.set, 43);
    std::vector<uint32_t> skip(rays.size());
    for (size_t i = 0; i < skip.size(); ++i) skip[i] = i % 3 == 0 ? kNoHit : static_cast<uint32_t>(i % 7);
    for (const VoxelHitMode mode : {VoxelHitMode::Cubes, VoxelHitMode::Contours}) {
      VoxelTracerOptions o;
      o.mode = mode;
      // The reference: brute force, or for the big shell the grid (equal to it, tests above).
      std::unique_ptr<VoxelTracer> brute =
          build_voxel_tracer(c.set.size() < 5000 ? "voxel_brute" : "grid", c.set, o);
      std::vector<Hit> ref(rays.size()), ref_skip(rays.size());
      std::vector<Vec3> ref_tr(rays.size());
      brute->intersect(rays, ref);
      brute->intersect_skipping(rays, skip, ref_skip);
      brute->transmittance(rays, ref_tr);
      // Passing through one voxel (skip_prim: the voxel a secondary ray leaves): every other ray
      // skips the voxel it would hit first, and must hit something else (or nothing).
      std::vector<uint32_t> leave(rays.size(), kNoHit);
      for (size_t i = 0; i < rays.size(); i += 2) leave[i] = ref[i].prim;
      std::vector<Hit> ref_leave(rays.size());
      brute->intersect_skipping(rays, {}, ref_leave, nullptr, leave);
      {  // the grid skips the same voxel
        const std::unique_ptr<VoxelTracer> grid = build_voxel_tracer("grid", c.set, o);
        std::vector<Hit> grid_leave(rays.size());
        grid->intersect_skipping(rays, {}, grid_leave, nullptr, leave);
        size_t differ = 0;
        for (size_t i = 0; i < rays.size(); ++i) differ += same_hit(ref_leave[i], grid_leave[i]) ? 0 : 1;
        EXPECT_EQ(differ, 0u) << c.name << " " << to_string(mode) << ": grid skipping the left voxel";
      }
      SparseVoxelOctree svo = SparseVoxelOctree::build(c.set, o);
      for (const Kernel& kernel : kKernels) {
        if (!kernel.runs()) continue;
        const PacketWidth limit(kernel.width, kernel.avx512);
        const std::string what = c.name + " " + to_string(mode) + " width " + kernel.name();
        std::vector<Hit> hits(rays.size()), hits_skip(rays.size()), hits_leave(rays.size());
        std::vector<Vec3> tr(rays.size());
        TraceStats st;
        svo.intersect(rays, hits, &st);
        svo.intersect_skipping(rays, skip, hits_skip);
        svo.intersect_skipping(rays, {}, hits_leave, nullptr, leave);
        svo.transmittance(rays, tr);
        size_t bad = 0, bad_skip = 0, bad_tr = 0, bad_leave = 0, hit_count = 0, left = 0;
        for (size_t i = 0; i < rays.size(); ++i) {
          hit_count += hits[i].hit() ? 1 : 0;
          if (!same_hit(ref_leave[i], hits_leave[i]) && ++bad_leave <= 3)
            ADD_FAILURE() << what << " leaving " << leave[i] << ": " << describe(hits_leave[i]) << " vs brute "
                          << describe(ref_leave[i]) << " for " << describe(rays[i]);
          if (leave[i] != kNoHit) {
            EXPECT_NE(hits_leave[i].prim, leave[i]) << what << ": hit the voxel it leaves, " << describe(rays[i]);
            ++left;
          }
          if (!same_hit(ref[i], hits[i]) && ++bad <= 3)
            ADD_FAILURE() << what << ": " << describe(hits[i]) << " vs brute " << describe(ref[i]) << " for " << describe(rays[i]);
          if (!same_hit(ref_skip[i], hits_skip[i]) && ++bad_skip <= 3)
            ADD_FAILURE() << what << " skip " << skip[i] << ": " << describe(hits_skip[i]) << " vs brute "
                          << describe(ref_skip[i]) << " for " << describe(rays[i]);
          if (!(ref_tr[i] == tr[i]) && ++bad_tr <= 3)
            ADD_FAILURE() << what << ": transmittance " << tr[i].x << " vs brute " << ref_tr[i].x << " for " << describe(rays[i]);
        }
        EXPECT_EQ(bad, 0u) << what;
        EXPECT_EQ(bad_skip, 0u) << what;
        EXPECT_EQ(bad_tr, 0u) << what;
        EXPECT_EQ(bad_leave, 0u) << what;
        EXPECT_GT(left, rays.size() / 20) << what;  // the skipping is exercised
        EXPECT_GT(hit_count, rays.size() / 10) << what;
        EXPECT_EQ(st.rays, rays.size()) << what;
        // One ray per call takes the single-ray path: the same answers.
        for (size_t i = 0; i < rays.size(); i += 5) {
          const Hit h = test::trace1(svo, rays[i]);
          if (!same_hit(h, hits[i])) {
            ADD_FAILURE() << what << ": single " << describe(h) << " vs batch " << describe(hits[i]) << " for " << describe(rays[i]);
            break;
          }
        }
      }
      // Level of detail: every kernel agrees with the single-ray traversal.
      svo.set_lod(c.set.grid.depth - 2);
      std::vector<Hit> lod_ref(rays.size());
      {
        const PacketWidth limit(1);
        svo.intersect(rays, lod_ref);
      }
      for (const Kernel& kernel : kKernels) {
        if (kernel.width == 1 || !kernel.runs()) continue;
        const PacketWidth limit(kernel.width, kernel.avx512);
        std::vector<Hit> hits(rays.size());
        svo.intersect(rays, hits);
        size_t bad = 0;
        for (size_t i = 0; i < rays.size(); ++i)
          if (!same_hit(lod_ref[i], hits[i]) && ++bad <= 3)
            ADD_FAILURE() << c.name << " lod width " << kernel.name() << ": " << describe(hits[i]) << " vs " << describe(lod_ref[i]);
        EXPECT_EQ(bad, 0u);
      }
    }
  }
}

// The packets compute each lane's crossing of a leaf (entry t, entry face, exit t) with vector
// operations instead of calling the kernel's cell_span (svo_packet.inc): ties between entry
// planes (rays through edges and corners), +-0 direction components (fixed axes, whose plane
// distances are -inf or +inf), origins on voxel planes, entry distances of -0 and tmin on a
// plane must all give the kernel's bits. Bundles of 16 rays of one octant, so they walk as
// packets down to the leaves; compared with the brute force per kernel width, in both modes.
TEST(SvoPacket, LeafSpansOfPacketsEqualTheKernelOnLatticeRays) {
  const VoxelGrid g = dyadic_grid(4);  // local = (world + 1) * 8: lattice points are exact
  const VoxelSet set = random_set(g, 1800, 77);
  std::mt19937 rng(78);
  const float s = g.voxel_size();
  const auto zero = [&] { return (rng() & 1) ? 0.0f : -0.0f; };
  const auto sign = [&] { return (rng() & 1) ? 1.0f : -1.0f; };
  std::vector<Ray> rays;
  for (int bundle = 0; bundle < 600; ++bundle) {
    const int kind = bundle % 4;
    // Direction signs and zeros shared by the bundle (one octant); magnitudes per lane.
    const Vec3 sg(sign(), sign(), sign());
    const int a0 = static_cast<int>(rng() % 3), a1 = (a0 + 1 + static_cast<int>(rng() % 2)) % 3;
    Vec3 base;
    for (int i = 0; i < 3; ++i) base[i] = static_cast<float>(static_cast<int>(rng() % 18) - 1);  // lattice, some outside
    for (int j = 0; j < 16; ++j) {
      Vec3 org = g.origin + base * s;
      org[a0] += static_cast<float>(j % 4) * s;  // neighbouring lattice points
      org[a1] += static_cast<float>(j / 4) * s;
      Vec3 d;
      switch (kind) {
        case 0:  // along one axis: two fixed axes
          d = Vec3(zero(), zero(), zero());
          d[a0] = sg[a0] * (0.5f + static_cast<float>(j % 3));
          break;
        case 1:  // in a plane: one fixed axis, lattice slopes (edge crossings)
          d = Vec3(sg.x * static_cast<float>(1 + j % 3), sg.y * static_cast<float>(1 + (j / 3) % 3),
                   sg.z * static_cast<float>(1 + j % 2));
          d[a0] = zero();
          break;
        case 2:  // a camera on a lattice point: every lane enters its first voxel at t = +-0
          // (negative components give -0), diagonals through corners tie on every axis
          org = g.origin + base * s;
          d = Vec3(sg.x * (1.0f + 0.5f * static_cast<float>(j % 4)), sg.y * (1.0f + 0.5f * static_cast<float>(j / 4)), sg.z);
          if (j % 5 == 0) d = Vec3(sg.x, sg.y, sg.z) * static_cast<float>(1 + j / 5);
          break;
        default: {  // generic directions, origin on a plane, offset along one axis
          std::uniform_real_distribution<float> u(0.1f, 1.0f);
          d = Vec3(sg.x * u(rng), sg.y * u(rng), sg.z * u(rng));
          org[a1] += 0.37f * s;
          break;
        }
      }
      // Windows: from 0, from -0, from a plane distance (t of the next lattice plane along a0),
      // and a bounded one ending on a plane.
      float tmin = 0.0f, tmax = kInf;
      switch (j % 4) {
        case 1: tmin = -0.0f; break;
        case 2: if (d[a0] != 0.0f) tmin = s / std::fabs(d[a0]); break;
        case 3: if (d[a0] != 0.0f) tmax = 3.0f * s / std::fabs(d[a0]); break;
        default: break;
      }
      rays.push_back(make_ray(org, d, tmin, tmax));
    }
  }
  std::vector<uint32_t> skip(rays.size());
  for (size_t i = 0; i < skip.size(); ++i) skip[i] = i % 2 == 0 ? kNoHit : static_cast<uint32_t>(i % 5);
  size_t starts_inside = 0, face_hits = 0;
  for (const VoxelHitMode mode : {VoxelHitMode::Cubes, VoxelHitMode::Contours}) {
    VoxelTracerOptions o;
    o.mode = mode;
    const std::unique_ptr<VoxelTracer> brute = build_voxel_tracer("voxel_brute", set, o);
    std::vector<Hit> ref(rays.size()), ref_skip(rays.size());
    std::vector<Vec3> ref_tr(rays.size());
    brute->intersect(rays, ref);
    brute->intersect_skipping(rays, skip, ref_skip);
    brute->transmittance(rays, ref_tr);
    for (size_t i = 0; i < rays.size(); ++i) {
      if (!ref[i].hit()) continue;
      (ref[i].t == rays[i].tmin ? starts_inside : face_hits) += 1;
    }
    const SparseVoxelOctree svo = SparseVoxelOctree::build(set, o);
    for (const Kernel& kernel : kKernels) {
      if (!kernel.runs()) continue;
      const PacketWidth limit(kernel.width, kernel.avx512);
      const std::string what = std::string(to_string(mode)) + " width " + kernel.name();
      std::vector<Hit> hits(rays.size()), hits_skip(rays.size());
      std::vector<Vec3> tr(rays.size());
      svo.intersect(rays, hits);
      svo.intersect_skipping(rays, skip, hits_skip);
      svo.transmittance(rays, tr);
      size_t bad = 0, bad_skip = 0, bad_tr = 0;
      for (size_t i = 0; i < rays.size(); ++i) {
        if (!same_hit(ref[i], hits[i]) && ++bad <= 3)
          ADD_FAILURE() << what << ": " << describe(hits[i]) << " vs brute " << describe(ref[i]) << " for " << describe(rays[i]);
        if (!same_hit(ref_skip[i], hits_skip[i]) && ++bad_skip <= 3)
          ADD_FAILURE() << what << " skip: " << describe(hits_skip[i]) << " vs brute " << describe(ref_skip[i]);
        if (!(ref_tr[i] == tr[i]) && ++bad_tr <= 3)
          ADD_FAILURE() << what << ": transmittance " << tr[i].x << " vs brute " << ref_tr[i].x << " for " << describe(rays[i]);
      }
      EXPECT_EQ(bad, 0u) << what;
      EXPECT_EQ(bad_skip, 0u) << what;
      EXPECT_EQ(bad_tr, 0u) << what;
    }
  }
  // Both entry cases are exercised (through a face; from inside a voxel, the kernel's axis -1).
  EXPECT_GT(face_hits, rays.size() / 4);
  EXPECT_GT(starts_inside, rays.size() / 50);
}

TEST(Svo, NaNAndDegenerateRaysMiss) {
  const VoxelSet set = block_set(dyadic_grid(3), 0, 7, 1);  // everything occupied
  const SparseVoxelOctree svo = SparseVoxelOctree::build(set);
  const std::vector<Ray> rays = {
      make_ray(Vec3(kNaN, 0, 0), Vec3(1, 0, 0)),     make_ray(Vec3(0, 0, 0), Vec3(kNaN, 1, 0)),
      make_ray(Vec3(0, 0, 0), Vec3(0, 0, 0)),        make_ray(Vec3(0, 0, 0), Vec3(-0.0f, 0.0f, -0.0f)),
      make_ray(Vec3(0, 0, 0), Vec3(1, 0, 0), kNaN),  make_ray(Vec3(0, 0, 0), Vec3(1, 0, 0), 0.0f, kNaN),
      make_ray(Vec3(0, 0, 0), Vec3(1, 0, 0), 2, 1),  make_ray(Vec3(kInf, 0, 0), Vec3(-1, 0, 0)),
      make_ray(Vec3(0, 0, 0), Vec3(kInf, 0, 0)),
  };
  std::vector<Hit> hits(rays.size());
  std::vector<Vec3> tr(rays.size());
  svo.intersect(rays, hits);
  svo.transmittance(rays, tr);
  for (size_t i = 0; i < rays.size(); ++i) {
    EXPECT_FALSE(hits[i].hit()) << describe(rays[i]);
    EXPECT_EQ(tr[i], Vec3(1.0f)) << describe(rays[i]);
  }
  // A sane ray does hit (the test can fail).
  Hit h;
  const Ray ok = make_ray(Vec3(0, 0, 0), Vec3(1, 0, 0));
  svo.intersect(std::span<const Ray>(&ok, 1), std::span<Hit>(&h, 1));
  EXPECT_TRUE(h.hit());
}

TEST(Svo, CubeNormalsAndInsideConvention) {
  VoxelSet set;
  set.grid = dyadic_grid(2);  // voxels of side 0.5 over [-1, 1]^3
  set.codes = {morton_encode(1, 1, 1)};  // [-0.5, 0]^3
  const SparseVoxelOctree svo = SparseVoxelOctree::build(set);
  const auto trace = [&](const Ray& r) {
    Hit h;
    svo.intersect(std::span<const Ray>(&r, 1), std::span<Hit>(&h, 1));
    return h;
  };
  Hit h = trace(make_ray(Vec3(-3, -0.25f, -0.25f), Vec3(2, 0, 0)));  // enters through x = -0.5
  ASSERT_TRUE(h.hit());
  EXPECT_EQ(h.prim, 0u);
  EXPECT_FLOAT_EQ(h.t, 1.25f);
  EXPECT_EQ(h.ng, Vec3(-1, 0, 0));
  h = trace(make_ray(Vec3(-0.25f, 2, -0.25f), Vec3(0, -1, -0.0f)));  // from +y
  ASSERT_TRUE(h.hit());
  EXPECT_FLOAT_EQ(h.t, 2.0f);
  EXPECT_EQ(h.ng, Vec3(0, 1, 0));
  // Starting inside: t = tmin, normal against the dominant direction axis.
  h = trace(make_ray(Vec3(-0.25f, -0.25f, -0.25f), Vec3(0.1f, -0.2f, 0.9f), 0.01f));
  ASSERT_TRUE(h.hit());
  EXPECT_EQ(h.t, 0.01f);
  EXPECT_EQ(h.ng, Vec3(0, 0, -1));
  // A ray running in the face plane y = 0 (the voxel's top face) belongs to the voxel above:
  // miss; in y = -0.5 (its bottom face) it belongs to this voxel: hit.
  EXPECT_FALSE(trace(make_ray(Vec3(-3, 0.0f, -0.25f), Vec3(1, 0, 0))).hit());
  EXPECT_TRUE(trace(make_ray(Vec3(-3, -0.5f, -0.25f), Vec3(1, -0.0f, 0))).hit());
  // Touching only the edge (x = 0, y = 0): no positive-length crossing, miss.
  EXPECT_FALSE(trace(make_ray(Vec3(-1, 1, -0.25f), Vec3(1, -1, 0))).hit());
  // Through the voxel's diagonal corner-to-corner: hit at the corner.
  h = trace(make_ray(Vec3(-1, -1, -1), Vec3(1, 1, 1)));
  ASSERT_TRUE(h.hit());
  EXPECT_FLOAT_EQ(h.t, 0.5f);
  EXPECT_EQ(h.ng, Vec3(-1, 0, 0));  // corner ties go to the lowest axis
}

TEST(Svo, ContourHitsAndParallelView) {
  VoxelSet set;
  set.grid = dyadic_grid(1);  // voxels of side 1 over [-1, 1]^3
  set.codes = {morton_encode(0, 0, 0), morton_encode(1, 0, 0)};
  VoxelAttributes a;
  a.normal = Vec3(0, 0, 1);
  a.contour_lo = -0.1f;  // slab z in [-0.6, -0.4]
  a.contour_hi = 0.1f;
  set.attrs = {a, a};
  VoxelTracerOptions o;
  o.mode = VoxelHitMode::Contours;
  const SparseVoxelOctree svo = SparseVoxelOctree::build(set, o);
  const auto trace = [&](const Ray& r) {
    Hit h;
    svo.intersect(std::span<const Ray>(&r, 1), std::span<Hit>(&h, 1));
    return h;
  };
  Hit h = trace(make_ray(Vec3(-0.5f, -0.5f, 2), Vec3(0, 0, -1)));
  ASSERT_TRUE(h.hit());
  EXPECT_NEAR(h.t, 2.4f, 1e-6f);
  EXPECT_EQ(h.ng, Vec3(0, 0, 1));
  // Parallel to the slab above it: passes through both voxels without a hit.
  EXPECT_FALSE(trace(make_ray(Vec3(-2, -0.5f, -0.2f), Vec3(1, 0, 0))).hit());
  // Parallel inside the slab: hits at the cube entry.
  h = trace(make_ray(Vec3(-2, -0.5f, -0.5f), Vec3(1, 0, 0)));
  ASSERT_TRUE(h.hit());
  EXPECT_FLOAT_EQ(h.t, 1.0f);
  VoxelTracerOptions cubes;
  const SparseVoxelOctree svo_cubes = SparseVoxelOctree::build(set, cubes);
  Hit hc;
  const Ray above = make_ray(Vec3(-2, -0.5f, -0.2f), Vec3(1, 0, 0));
  svo_cubes.intersect(std::span<const Ray>(&above, 1), std::span<Hit>(&hc, 1));
  EXPECT_TRUE(hc.hit());
}

TEST(Svo, TransmittanceAgreesAndCountsEachVoxelOnce) {
  VoxelSet set = make_sphere_shell_set(generic_grid(5), generic_grid(5).origin + Vec3(1.85f), 1.2f, 1);
  for (auto& a : set.attrs) a.transparency = a.material == 0 ? 0.0f : 0.5f + 0.1f * static_cast<float>(a.material);
  for (const VoxelHitMode mode : {VoxelHitMode::Cubes, VoxelHitMode::Contours}) {
    VoxelTracerOptions o;
    o.mode = mode;
    const SparseVoxelOctree svo = SparseVoxelOctree::build(set, o);
    const VoxelGridTracer grid = VoxelGridTracer::build(set, o);
    const voxel::VoxelBruteTracer brute(set, o);
    const std::vector<Ray> rays = make_rays(set, 8000, 17);
    EXPECT_EQ(compare_transmittance(brute, svo, rays, to_string(mode)), 0u);
    EXPECT_EQ(compare_transmittance(brute, grid, rays, to_string(mode)), 0u);
    std::vector<Vec3> tr(rays.size());
    svo.transmittance(rays, tr);
    EXPECT_GT(std::count_if(tr.begin(), tr.end(), [](const Vec3& v) { return v.x > 0.0f && v.x < 1.0f; }), 50);
    EXPECT_GT(std::count_if(tr.begin(), tr.end(), [](const Vec3& v) { return v.x == 0.0f; }), 50);
  }
  // Two voxels of transparency 0.5 in a row: 0.25 exactly, with an axis-parallel ray along
  // their shared face plane counted once per voxel.
  VoxelSet two;
  two.grid = dyadic_grid(1);
  two.codes = {morton_encode(0, 0, 0), morton_encode(1, 0, 0)};
  VoxelAttributes a;
  a.transparency = 0.5f;
  two.attrs = {a, a};
  const SparseVoxelOctree svo2 = SparseVoxelOctree::build(two);
  const Ray r = make_ray(Vec3(-2, -0.5f, -1.0f), Vec3(1, 0, 0.0f));
  Vec3 t;
  svo2.transmittance(std::span<const Ray>(&r, 1), std::span<Vec3>(&t, 1));
  EXPECT_EQ(t, Vec3(0.25f));
}

TEST(SvoLod, TracingAtLodEqualsTheCoarsenedSet) {
  const VoxelSet sets[] = {make_sphere_shell_set(dyadic_grid(7), Vec3(0.1f, 0.0f, -0.05f), 0.7f),
                           random_set(generic_grid(6), 3000, 8)};
  for (const VoxelSet& set : sets) {
    const int depth = set.grid.depth;
    for (const VoxelHitMode mode : {VoxelHitMode::Cubes, VoxelHitMode::Contours}) {
      VoxelTracerOptions o;
      o.mode = mode;
      SparseVoxelOctree svo = SparseVoxelOctree::build(set, o);
      const std::vector<Ray> rays = make_rays(set, 5000, 23);
      for (int level = 1; level < depth; ++level) {
        svo.set_lod(level);
        const VoxelSet coarse = svo.level_set(level);
        // The coarsened codes are codes >> 3 (depth - level), unique.
        std::vector<uint64_t> expect;
        for (const uint64_t c : set.codes) expect.push_back(c >> (3 * (depth - level)));
        expect.erase(std::unique(expect.begin(), expect.end()), expect.end());
        ASSERT_EQ(coarse.codes, expect);
        const SparseVoxelOctree ref = SparseVoxelOctree::build(coarse, o);
        std::vector<Hit> hl(rays.size()), hr(rays.size());
        svo.intersect(rays, hl);
        ref.intersect(rays, hr);
        const uint32_t n = static_cast<uint32_t>(set.size()), base = svo.level_offsets()[static_cast<size_t>(level)];
        size_t bad = 0, hits = 0;
        for (size_t i = 0; i < rays.size(); ++i) {
          Hit mapped = hr[i];
          if (mapped.hit()) {
            mapped.prim += n + base;
            ++hits;
          }
          if (!same_hit(hl[i], mapped) && ++bad <= 3)
            ADD_FAILURE() << "level " << level << ": lod " << describe(hl[i]) << " vs coarse " << describe(mapped)
                          << " for " << describe(rays[i]);
        }
        EXPECT_EQ(bad, 0u);
        EXPECT_GT(hits, 100u);
        const auto any = std::find_if(hl.begin(), hl.end(), [](const Hit& h) { return h.hit(); });
        ASSERT_NE(any, hl.end());
        EXPECT_GE(any->prim, n);
        EXPECT_EQ(&svo.attributes(any->prim), &svo.inner_attributes()[any->prim - n]);
      }
      svo.set_lod(0);
      const voxel::VoxelBruteTracer brute(set, o);
      EXPECT_EQ(compare_hits(brute, svo, std::span<const Ray>(rays).first(1000), "lod 0"), 0u);
      svo.set_lod(depth + 3);  // beyond the depth = full depth
      EXPECT_EQ(compare_hits(brute, svo, std::span<const Ray>(rays).first(1000), "lod > depth"), 0u);
    }
  }
  SparseVoxelOctree svo;
  EXPECT_THROW(svo.set_lod(-1), Error);
}

TEST(SvoLod, InnerAttributesAreAveragedAndContoursConservative) {
  const VoxelSet set = random_set(dyadic_grid(5), 2500, 9);
  const SparseVoxelOctree svo = SparseVoxelOctree::build(set);
  // Root colour = mean over the voxels (nested averaging weighted by counts).
  Vec3 mean;
  for (const auto& a : set.attrs) mean += a.colour;
  mean = mean / static_cast<float>(set.size());
  const VoxelAttributes& root = svo.inner_attributes()[0];
  EXPECT_NEAR(root.colour.x, mean.x, 1e-4f);
  EXPECT_NEAR(root.colour.y, mean.y, 1e-4f);
  EXPECT_NEAR(root.colour.z, mean.z, 1e-4f);
  for (int l = 0; l < set.grid.depth; ++l)
    for (const auto& a : svo.level_set(l).attrs) EXPECT_NEAR(length(a.normal), 1.0f, 1e-5f);
  // Every point of every leaf's contour polygon (sampled) lies in every ancestor's slab.
  std::vector<VoxelSet> levels;
  for (int l = 0; l <= set.grid.depth; ++l) levels.push_back(svo.level_set(l));
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u01(0.0f, 1.0f);
  size_t checked = 0;
  for (size_t i = 0; i < set.size(); i += 7) {
    uint32_t x, y, z;
    morton_decode(set.codes[i], x, y, z);
    const Aabb box = set.grid.voxel_box(x, y, z);
    const Vec3 c = box.center();
    const VoxelAttributes& a = set.attrs[i];
    for (int s = 0; s < 64; ++s) {
      const Vec3 p = box.min + Vec3(u01(rng), u01(rng), u01(rng)) * set.grid.voxel_size();
      const float d = dot(a.normal, p - c);
      if (d < a.contour_lo || d > a.contour_hi) continue;
      for (int l = 0; l < set.grid.depth; ++l) {
        const uint64_t code = set.codes[i] >> (3 * (set.grid.depth - l));
        const auto& lv = levels[static_cast<size_t>(l)];
        const size_t j = static_cast<size_t>(std::lower_bound(lv.codes.begin(), lv.codes.end(), code) - lv.codes.begin());
        ASSERT_LT(j, lv.codes.size());
        uint32_t nx, ny, nz;
        morton_decode(code, nx, ny, nz);
        VoxelGrid g = set.grid;
        g.depth = l;
        const Vec3 nc = g.voxel_box(nx, ny, nz).center();
        const VoxelAttributes& na = lv.attrs[j];
        const float dn = dot(na.normal, p - nc);
        const float eps = 1e-5f * g.voxel_size();
        EXPECT_GE(dn, na.contour_lo - eps) << "level " << l;
        EXPECT_LE(dn, na.contour_hi + eps) << "level " << l;
        ++checked;
      }
    }
  }
  EXPECT_GT(checked, 1000u);
}

TEST(SvoMemory, ProportionalToVoxelCount) {
  for (const int depth : {16, 21}) {
    VoxelSet one;
    one.grid = dyadic_grid(depth);
    one.codes = {morton_encode(12345, 999, (1u << depth) - 1)};
    SvoInfo info;
    const SparseVoxelOctree svo = SparseVoxelOctree::build(one, {}, &info);
    EXPECT_EQ(svo.nodes().size(), static_cast<size_t>(depth));
    EXPECT_LT(svo.memory_bytes(), 64u * static_cast<size_t>(depth) + 200u);
    EXPECT_EQ(info.voxels, 1u);
    EXPECT_EQ(svo.to_voxel_set().codes, one.codes);
  }
  const VoxelSet scattered = random_set(dyadic_grid(16), 1000, 4);
  const SparseVoxelOctree s2 = SparseVoxelOctree::build(scattered);
  EXPECT_LE(s2.nodes().size(), scattered.size() * 16);
  // A surface: bytes per voxel reported.
  SvoInfo info;
  const VoxelSet shell = make_sphere_shell_set(dyadic_grid(8), Vec3(0.0f), 0.9f);
  const SparseVoxelOctree s3 = SparseVoxelOctree::build(shell, {}, &info);
  EXPECT_LT(info.node_bytes_per_voxel, 4.0);
  EXPECT_LT(info.bytes_per_voxel, 48.0 + 8.0 + 48.0 / 2.0);
  RecordProperty("shell_d8_voxels", std::to_string(info.voxels));
  RecordProperty("shell_d8_node_bytes_per_voxel", std::to_string(info.node_bytes_per_voxel));
  RecordProperty("shell_d8_bytes_per_voxel", std::to_string(info.bytes_per_voxel));
  std::printf("[ info     ] shell depth 8: %zu voxels, %zu nodes, %.2f node bytes/voxel, %.2f bytes/voxel total\n",
              info.voxels, info.nodes, info.node_bytes_per_voxel, info.bytes_per_voxel);
}

// Skip spans shorter than the ray span are a caller's error: every voxel tracer refuses them
// with a clear message instead of reading past their end.
TEST(Svo, SkipSpansShorterThanTheRaysAreRejected) {
  const VoxelSet set = random_set(dyadic_grid(4), 50, 9);
  const std::vector<Ray> rays = make_rays(set, 8, 10);
  const std::vector<uint32_t> short_span(rays.size() - 1, kNoHit), full(rays.size(), kNoHit);
  std::vector<Hit> hits(rays.size());
  for (const char* kind : {"svo", "grid", "voxel_brute"}) {
    const std::unique_ptr<VoxelTracer> t = build_voxel_tracer(kind, set);
    const auto message = [&](auto&& call) {
      try {
        call();
      } catch (const Error& e) {
        return std::string(e.what());
      }
      return std::string("no error");
    };
    EXPECT_NE(message([&] { t->intersect_skipping(rays, short_span, hits); }).find("skip span smaller"),
              std::string::npos) << kind;
    EXPECT_NE(message([&] { t->intersect_skipping(rays, {}, hits, nullptr, short_span); }).find("skip_prim span smaller"),
              std::string::npos) << kind;
    EXPECT_NO_THROW(t->intersect_skipping(rays, full, hits, nullptr, full)) << kind;  // the right length is fine
  }
}

TEST(Svo, BuildRejectsInvalidSets) {
  VoxelSet ok = random_set(dyadic_grid(3), 20, 1);
  EXPECT_NO_THROW(SparseVoxelOctree::build(ok));
  VoxelSet s = ok;
  std::swap(s.codes[0], s.codes[1]);
  EXPECT_THROW(SparseVoxelOctree::build(s), Error);
  s = ok;
  s.codes[1] = s.codes[0];
  EXPECT_THROW(SparseVoxelOctree::build(s), Error);
  s = ok;
  s.codes.back() = 512;  // 8^3
  EXPECT_THROW(SparseVoxelOctree::build(s), Error);
  s = ok;
  s.attrs.pop_back();
  EXPECT_THROW(SparseVoxelOctree::build(s), Error);
  s = ok;
  s.attrs[3].normal.x = kNaN;
  EXPECT_THROW(SparseVoxelOctree::build(s), Error);
  s = ok;
  s.attrs[3].contour_lo = 1.0f, s.attrs[3].contour_hi = 0.0f;
  EXPECT_THROW(SparseVoxelOctree::build(s), Error);
  s = ok;
  s.grid.depth = 22;
  EXPECT_THROW(SparseVoxelOctree::build(s), Error);
  s = ok;
  s.grid.side = 0.0f;
  EXPECT_THROW(SparseVoxelOctree::build(s), Error);
  EXPECT_THROW(build_voxel_tracer("octree", ok), Error);
  EXPECT_THROW(parse_voxel_hit_mode("spheres"), Error);
  EXPECT_EQ(parse_voxel_hit_mode("contours"), VoxelHitMode::Contours);
  const SparseVoxelOctree svo = SparseVoxelOctree::build(ok);
  EXPECT_THROW(svo.attributes(static_cast<uint32_t>(ok.size() + svo.nodes().size())), Error);
}

/// Large sets are built by chunks of voxels in parallel: the tree must not depend on the thread
/// count or on which build() was called, its levels must be the input's shifted codes, and an
/// invalid voxel in any chunk must get validate_set's message (with its index).
TEST(Svo, ChunkedBuildIsDeterministicAndChecksEveryChunk) {
  const VoxelSet set = random_set(dyadic_grid(10), 400000, 21);
  ASSERT_GT(set.size(), 300000u);
  std::vector<SparseVoxelOctree> trees;
  for (const int threads : {1, 2, 0}) {  // 0: all hardware threads
    VoxelTracerOptions o;
    o.threads = threads;
    trees.push_back(SparseVoxelOctree::build(set, o));
    VoxelSet moved = set;
    trees.push_back(SparseVoxelOctree::build(std::move(moved), o));
  }
  const SparseVoxelOctree& ref = trees.front();
  for (int l = 0; l <= set.grid.depth; ++l) {
    std::vector<uint64_t> want;
    for (const uint64_t c : set.codes) {
      const uint64_t p = c >> (3 * (set.grid.depth - l));
      if (want.empty() || want.back() != p) want.push_back(p);
    }
    EXPECT_EQ(ref.level_set(l).codes, want) << "level " << l;
  }
  for (const SparseVoxelOctree& t : trees) {
    ASSERT_EQ(t.nodes().size(), ref.nodes().size());
    EXPECT_EQ(std::memcmp(t.nodes().data(), ref.nodes().data(), ref.nodes().size_bytes()), 0);
    EXPECT_EQ(std::memcmp(t.inner_attributes().data(), ref.inner_attributes().data(),
                          ref.inner_attributes().size_bytes()),
              0);
    EXPECT_EQ(std::memcmp(t.leaf_attributes().data(), set.attrs.data(), ref.leaf_attributes().size_bytes()), 0);
    EXPECT_TRUE(std::equal(t.level_offsets().begin(), t.level_offsets().end(), ref.level_offsets().begin(),
                           ref.level_offsets().end()));
  }

  auto message = [](VoxelSet s, bool move) {
    VoxelTracerOptions o;
    o.threads = 2;
    try {
      if (move) {
        const size_t attrs = s.attrs.size();
        try {
          SparseVoxelOctree::build(std::move(s), o);
        } catch (const Error&) {
          // NOLINTNEXTLINE(bugprone-use-after-move): an invalid set is left as it was given
          EXPECT_EQ(s.attrs.size(), attrs);
          throw;
        }
      } else {
        SparseVoxelOctree::build(s, o);
      }
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  for (const size_t at : {size_t{1}, set.size() / 2 + 17, set.size() - 1}) {
    for (const bool move : {false, true}) {
      VoxelSet s = set;
      s.attrs[at].colour.y = std::numeric_limits<float>::infinity();
      EXPECT_EQ(message(s, move), "svo: voxel " + std::to_string(at) + ": non-finite attributes or contour_lo > contour_hi");
      s = set;
      s.attrs[at].contour_lo = s.attrs[at].contour_hi + 1.0f;
      EXPECT_EQ(message(s, move), "svo: voxel " + std::to_string(at) + ": non-finite attributes or contour_lo > contour_hi");
      s = set;
      s.codes[at] = s.codes[at - 1];
      EXPECT_EQ(message(s, move), "svo: voxel codes must be sorted ascending and unique (voxel " + std::to_string(at) + ")");
    }
  }
}

TEST(Svo, DepthZeroEmptyAndFactory) {
  VoxelSet one;
  one.grid = generic_grid(0);
  one.codes = {0};
  VoxelSet empty;
  empty.grid = generic_grid(5);
  for (const VoxelSet* set : {&one, &empty}) {
    for (const char* kind : {"svo", "grid", "voxel_brute"}) {
      const auto t = build_voxel_tracer(kind, *set);
      EXPECT_EQ(t->name(), kind);
      EXPECT_EQ(t->voxel_count(), set->size());
    }
    const auto svo = build_voxel_tracer("svo", *set);
    const auto grid = build_voxel_tracer("grid", *set);
    const voxel::VoxelBruteTracer brute(*set);
    const std::vector<Ray> rays = make_rays(*set, 3000, 2);
    EXPECT_EQ(compare_hits(brute, *svo, rays, "svo"), 0u);
    EXPECT_EQ(compare_hits(brute, *grid, rays, "grid"), 0u);
  }
  EXPECT_EQ(SparseVoxelOctree::build(one).to_voxel_set().codes, one.codes);
  EXPECT_TRUE(SparseVoxelOctree::build(empty).to_voxel_set().codes.empty());
}

}  // namespace
}  // namespace specula

namespace specula {
namespace {

// Seed 000's setup (RenderOptions::shadows = false): no shadow ray is traced, every light
// sample is added unoccluded, so no pixel gets darker and shadowed ones get brighter; the
// primary and secondary rays are the same.
TEST(SvoRender, WithoutShadowRaysLightsAreUnoccluded) {
  LoadOptions lo;
  lo.warn = [](const std::string&) {};
  const Scene scene = make_builtin_scene("cornell", lo);
  SceneVoxelOptions vo;
  vo.depth = 6;
  const auto svo = voxelize_scene(scene, vo);
  RenderOptions ro;
  ro.width = 48;
  ro.height = 36;
  ro.threads = 2;
  RenderStats with, without;
  const Film a = render_whitted(scene, *svo, ro, &with);
  ro.shadows = false;
  const Film b = render_whitted(scene, *svo, ro, &without);
  EXPECT_GT(with.shadow_rays, 0u);
  EXPECT_EQ(without.shadow_rays, 0u);
  EXPECT_EQ(without.primary_rays, with.primary_rays);
  EXPECT_EQ(without.secondary_rays, with.secondary_rays);
  size_t brighter = 0;
  for (size_t i = 0; i < a.color.size(); ++i) {
    for (int c = 0; c < 3; ++c) EXPECT_GE(b.color[i][c], a.color[i][c] - 1e-6f * (1.0f + a.color[i][c])) << i;
    brighter += b.color[i].x > a.color[i].x + 1e-3f ? 1 : 0;
  }
  EXPECT_GT(brighter, a.color.size() / 50);  // some pixels were in shadow
}

// Seed 001's medium rule: a ray skipping material m passes every voxel of material m and stops
// at the first voxel of another material; the same answer as tracing the set without the
// voxels of m (prims mapped back), in every voxel tracer, for both hit modes.
TEST(VoxelSkip, SkippingAMaterialEqualsTracingTheSetWithoutIt) {
  const VoxelSet set = random_set(dyadic_grid(5), 3000, 31);
  const std::vector<Ray> rays = make_rays(set, 4000, 32);
  for (const VoxelHitMode mode : {VoxelHitMode::Cubes, VoxelHitMode::Contours}) {
    VoxelTracerOptions opt;
    opt.mode = mode;
    for (const uint32_t m : {0u, 3u, 6u}) {
      VoxelSet without;
      without.grid = set.grid;
      std::vector<uint32_t> back;  // index in `without` -> index in `set`
      for (size_t i = 0; i < set.size(); ++i)
        if (set.attrs[i].material != m) {
          without.codes.push_back(set.codes[i]);
          without.attrs.push_back(set.attrs[i]);
          back.push_back(static_cast<uint32_t>(i));
        }
      const auto reference = build_voxel_tracer("voxel_brute", without, opt);
      std::vector<Hit> expected(rays.size());
      reference->intersect(rays, expected);
      const std::vector<uint32_t> skip(rays.size(), m);
      for (const char* kind : {"svo", "grid", "voxel_brute"}) {
        const auto tracer = build_voxel_tracer(kind, set, opt);
        std::vector<Hit> hits(rays.size());
        tracer->intersect_skipping(rays, skip, hits);
        for (size_t r = 0; r < rays.size(); ++r) {
          const uint32_t want = expected[r].hit() ? back[expected[r].prim] : kNoHit;
          ASSERT_EQ(hits[r].prim, want) << kind << " " << to_string(mode) << " skip " << m << " ray " << r;
          if (want != kNoHit) {
            ASSERT_EQ(hits[r].t, expected[r].t) << kind << " ray " << r;
          }
        }
        // Without a skip list (or kNoHit entries) nothing is skipped.
        std::vector<Hit> plain(rays.size()), none(rays.size());
        tracer->intersect(rays, plain);
        tracer->intersect_skipping(rays, std::vector<uint32_t>(rays.size(), kNoHit), none);
        for (size_t r = 0; r < rays.size(); ++r) ASSERT_EQ(plain[r].prim, none[r].prim) << kind << " ray " << r;
      }
    }
  }
}

/// The chunked build's attribute check (validate_set's rule: every float finite, contour_lo <=
/// contour_hi) looks at every float field, and never at the material id (any bits are valid,
/// also those of a float NaN).
TEST(Svo, AttributeCheckCoversEveryFloatAndNotTheMaterial) {
  const VoxelSet set = random_set(dyadic_grid(8), 60000, 5);
  ASSERT_GT(set.size(), 40000u);
  const size_t at = set.size() / 3 + 5;
  VoxelTracerOptions o;
  o.threads = 2;
  for (int field = 0; field < 11; ++field) {
    for (const float bad : {std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity(),
                            -std::numeric_limits<float>::infinity()}) {
      VoxelSet s = set;
      float f[11];
      std::memcpy(f, &s.attrs[at], sizeof f);
      f[field] = bad;
      std::memcpy(static_cast<void*>(&s.attrs[at]), f, sizeof f);
      std::string what = "no error";
      try {
        SparseVoxelOctree::build(s, o);
      } catch (const Error& e) {
        what = e.what();
      }
      EXPECT_EQ(what, "svo: voxel " + std::to_string(at) + ": non-finite attributes or contour_lo > contour_hi")
          << "field " << field;
    }
  }
  for (const uint32_t material : {0x7fc00000u, 0xffffffffu, 0x7f800000u, 1u}) {
    VoxelSet s = set;
    s.attrs[at].material = material;
    const SparseVoxelOctree t = SparseVoxelOctree::build(s, o);
    EXPECT_EQ(t.leaf_attributes()[at].material, material);
  }
}

}  // namespace
}  // namespace specula
