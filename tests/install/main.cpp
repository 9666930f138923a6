// A library user's program: find_package(specula), build a BVH over a built-in scene, render.
#include <specula/accel.h>
#include <specula/load.h>
#include <specula/render.h>

#include <cstdio>

int main() {
  const specula::Scene scene = specula::make_builtin_scene("cornell");
  const auto tracer = specula::build_tracer(specula::AccelKind::Bvh, {scene.positions, scene.indices, {}});
  specula::RenderOptions options;
  options.width = 32;
  options.height = 24;
  const specula::Film film = specula::render_whitted(scene, *tracer, options);
  std::printf("rendered %dx%d\n", film.width, film.height);
  return film.color.size() == 32u * 24u ? 0 : 1;
}
