// Writing the film's AOV planes as images (owner: render).
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

#include "core/hash.h"
#include "io/image_util.h"
#include "specula/error.h"
#include "specula/image.h"

namespace specula {

namespace {

/// A perceptually ordered heat ramp: black, blue, magenta, orange, yellow, white.
Vec3 heat(float t) {
  static const Vec3 stops[] = {{0.0f, 0.0f, 0.0f}, {0.05f, 0.05f, 0.6f}, {0.6f, 0.05f, 0.55f},
                               {0.95f, 0.4f, 0.05f}, {1.0f, 0.9f, 0.1f}, {1.0f, 1.0f, 1.0f}};
  constexpr int n = static_cast<int>(sizeof stops / sizeof stops[0]);
  t = std::clamp(std::isfinite(t) ? t : 0.0f, 0.0f, 1.0f) * static_cast<float>(n - 1);
  const int i = std::min(static_cast<int>(t), n - 2);
  return lerp(stops[i], stops[i + 1], t - static_cast<float>(i));
}


/// Colours already in display space are written without the sRGB curve a second time.
void write_display_png(const std::string& path, int w, int h, const std::vector<Vec3>& display) {
  std::vector<uint8_t> px(display.size() * 3);
  for (size_t i = 0; i < display.size(); ++i)
    for (int c = 0; c < 3; ++c) {
      const float v = std::clamp(std::isfinite(display[i][c]) ? display[i][c] : 0.0f, 0.0f, 1.0f);
      px[3 * i + static_cast<size_t>(c)] = static_cast<uint8_t>(std::lround(v * 255.0f));
    }
  write_file_atomic(path, encode_png_srgb8(w, h, px));
}

}  // namespace

namespace {

bool is_exr(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return ext == ".exr";
}

}  // namespace

std::string aov_path(const std::string& base_path, Aov aov) {
  const std::filesystem::path base(base_path);
  const std::string ext = is_exr(base_path) ? base.extension().string() : ".png";
  return (base.parent_path() / (base.stem().string() + "." + aov_name(aov) + ext)).string();
}

std::vector<std::string> write_aovs(const std::string& base_path, const Film& film) {
  const bool exr = is_exr(base_path);
  auto name_for = [&](Aov aov) { return aov_path(base_path, aov); };
  const int w = film.width, h = film.height;
  const size_t n = static_cast<size_t>(std::max(w, 0)) * static_cast<size_t>(std::max(h, 0));
  std::vector<std::string> written;
  std::vector<Vec3> img(n);

  if (n > 0 && film.depth.size() == n) {
    const std::string path = name_for(Aov::Depth);
    if (exr) {
      for (size_t i = 0; i < n; ++i) img[i] = Vec3{film.depth[i]};
      write_exr(path, w, h, img);
    } else {  // grey: near = white, far = dark, miss = black
      float lo = kInf, hi = -kInf;
      for (float d : film.depth)
        if (std::isfinite(d)) lo = std::min(lo, d), hi = std::max(hi, d);
      const float span = hi > lo ? hi - lo : 1.0f;
      for (size_t i = 0; i < n; ++i)
        img[i] = std::isfinite(film.depth[i]) ? Vec3{1.0f - 0.85f * (film.depth[i] - lo) / span} : Vec3{};
      write_display_png(path, w, h, img);
    }
    written.push_back(path);
  }
  if (n > 0 && film.normal.size() == n) {
    const std::string path = name_for(Aov::Normal);
    if (exr) {
      write_exr(path, w, h, film.normal);
    } else {
      for (size_t i = 0; i < n; ++i)
        img[i] = film.normal[i] == Vec3{} ? Vec3{} : film.normal[i] * 0.5f + Vec3{0.5f};
      write_display_png(path, w, h, img);
    }
    written.push_back(path);
  }
  if (n > 0 && film.prim_id.size() == n) {
    const std::string path = name_for(Aov::PrimId);
    for (size_t i = 0; i < n; ++i) {
      if (film.prim_id[i] == kNoHit) {
        img[i] = Vec3{};
        continue;
      }
      const uint32_t hsh = hash_u32(film.prim_id[i]);
      img[i] = Vec3{0.2f + 0.8f * static_cast<float>(hsh & 0xFF) / 255.0f,
                    0.2f + 0.8f * static_cast<float>((hsh >> 8) & 0xFF) / 255.0f,
                    0.2f + 0.8f * static_cast<float>((hsh >> 16) & 0xFF) / 255.0f};
    }
    if (exr) write_exr(path, w, h, img);
    else write_display_png(path, w, h, img);
    written.push_back(path);
  }
  if (n > 0 && film.cost.size() == n) {
    const std::string path = name_for(Aov::Cost);
    if (exr) {
      for (size_t i = 0; i < n; ++i) img[i] = Vec3{static_cast<float>(film.cost[i])};
      write_exr(path, w, h, img);
    } else {  // heat map normalised to the 99th percentile so a few outliers do not wash it out
      std::vector<uint32_t> sorted(film.cost);
      const size_t k = std::min(n - 1, static_cast<size_t>(0.99 * static_cast<double>(n)));
      std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(k), sorted.end());
      const float top = std::max(1.0f, static_cast<float>(sorted[k]));
      for (size_t i = 0; i < n; ++i) img[i] = heat(static_cast<float>(film.cost[i]) / top);
      write_display_png(path, w, h, img);
    }
    written.push_back(path);
  }
  return written;
}

}  // namespace specula
