#include "render_scenes.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <limits>

#include <gtest/gtest.h>

#include "deepcanvas/protocol/density_model.hpp"
#include "deepcanvas/server_core/painter.hpp"

namespace deepcanvas::render_test {

namespace {
std::vector<server_core::CellIndex> leaves_of(const Octree& tree) {
  std::vector<server_core::CellIndex> out, stack;
  for (std::uint32_t r = 0; r < tree.root_count(); ++r) stack.push_back(r);
  while (!stack.empty()) {
    const auto c = stack.back();
    stack.pop_back();
    if (tree.is_leaf(c)) {
      out.push_back(c);
    } else {
      for (std::uint32_t s = 0; s < 8; ++s) stack.push_back(tree.first_child(c) + s);
    }
  }
  return out;
}
}  // namespace

std::unique_ptr<Octree> random_tree(std::uint64_t seed, int refines, int max_depth,
                                    server_core::OctreeConfig config) {
  auto created = Octree::create(config);
  EXPECT_TRUE(created.ok());
  auto tree = std::move(created).value();
  std::mt19937_64 rng(seed);
  // Refine near a few random centres so refinement clusters (as painting does) and reaches
  // depth, instead of spreading over the 64 roots.
  std::uniform_real_distribution<double> unit(-0.5, 0.5);
  std::vector<DVec3> centres;
  for (int i = 0; i < 3; ++i) {
    centres.push_back({unit(rng) * config.edge_m * 0.8, unit(rng) * config.edge_m * 0.8,
                       unit(rng) * config.edge_m * 0.8});
  }
  for (int i = 0; i < refines; ++i) {
    const DVec3& c = centres[rng() % centres.size()];
    // Spreads from 15% of the canvas down to 15% / 2^11: a few broad, many deep refinements.
    const double spread = std::ldexp(config.edge_m * 0.15, -static_cast<int>(rng() % 12));
    const server_core::Vec3d p{c.x + unit(rng) * spread, c.y + unit(rng) * spread,
                               c.z + unit(rng) * spread};
    auto loc = tree->locate({std::clamp(p.x, -config.edge_m / 2, config.edge_m / 2),
                             std::clamp(p.y, -config.edge_m / 2, config.edge_m / 2),
                             std::clamp(p.z, -config.edge_m / 2, config.edge_m / 2)},
                            max_depth);
    EXPECT_TRUE(loc.ok());
    if (!loc.ok() || loc->coord.depth >= max_depth) continue;
    auto r = tree->refine(loc->cell);
    EXPECT_TRUE(r.ok());
  }
  for (auto c : leaves_of(*tree)) {
    const std::uint64_t v = rng();
    const std::uint32_t kind = static_cast<std::uint32_t>(v % 8);
    std::uint32_t a;
    if (kind < 2) {
      a = 0;
    } else if (kind == 2) {
      a = 255;
    } else {
      a = 1 + static_cast<std::uint32_t>((v >> 8) % 254);
    }
    const std::uint32_t rgb = static_cast<std::uint32_t>(v >> 20) & 0xFFFFFFu;
    tree->set_colour(c, a == 0 ? 0u : (rgb | (a << 24)));
  }
  tree->recompute_masked_links();
  // Interior values current, as a server sends them: the renderers step over empty subtrees.
  tree->refresh_interior_colours();
  return tree;
}

void refine_around(Octree& tree, const std::vector<DVec3>& points, int depth) {
  for (const DVec3& p : points) {
    for (;;) {
      auto loc = tree.locate({p.x, p.y, p.z}, depth);
      ASSERT_TRUE(loc.ok());
      if (loc->coord.depth >= depth) break;
      ASSERT_TRUE(tree.refine(loc->cell).ok());
    }
  }
  tree.recompute_masked_links();
}

std::vector<LeafBox> leaf_boxes(const Octree& tree) {
  std::vector<LeafBox> out;
  for (auto c : leaves_of(tree)) {
    const auto coord = tree.coord(c);
    const auto b = tree.bounds_m(coord);
    out.push_back({{b.min.x, b.min.y, b.min.z},
                   {b.max.x, b.max.y, b.max.z},
                   tree.cell_edge_m(coord.depth),
                   tree.colour(c)});
  }
  return out;
}

std::vector<LeafSegment> painted_segments(const std::vector<LeafBox>& leaves, const DVec3& o,
                                          const DVec3& d) {
  std::vector<LeafSegment> segs;
  for (const LeafBox& l : leaves) {
    if ((l.colour >> 24) == 0) continue;  // empty leaves add nothing
    double t0 = 0, t1 = std::numeric_limits<double>::infinity();
    bool hit = true;
    for (int a = 0; a < 3 && hit; ++a) {
      if (d[a] == 0) {
        hit = o[a] >= l.min[a] && o[a] <= l.max[a];
        continue;
      }
      double ta = (l.min[a] - o[a]) / d[a], tb = (l.max[a] - o[a]) / d[a];
      if (ta > tb) std::swap(ta, tb);
      t0 = std::max(t0, ta);
      t1 = std::min(t1, tb);
      hit = t0 < t1;
    }
    if (hit) segs.push_back({t0, t1, &l});
  }
  std::sort(segs.begin(), segs.end(),
            [](const LeafSegment& a, const LeafSegment& b) { return a.t0 < b.t0; });
  return segs;
}

RenderImage brute_force_render(const std::vector<LeafBox>& leaves, const Camera& camera,
                               std::array<double, 3> background) {
  RenderImage img;
  img.width = camera.width();
  img.height = camera.height();
  img.rgba.resize(std::size_t{img.width} * img.height * 4);
  const DVec3 o = camera.position();
  for (std::uint32_t y = 0; y < img.height; ++y) {
    for (std::uint32_t x = 0; x < img.width; ++x) {
      protocol::density::Composite comp;
      for (const LeafSegment& s : painted_segments(leaves, o, camera.ray_direction(x, y)))
        comp.add(s.leaf->colour, (s.t1 - s.t0) / s.leaf->edge);
      double* px = &img.rgba[(std::size_t{y} * img.width + x) * 4];
      for (int c = 0; c < 3; ++c) px[c] = comp.rgb[c] + comp.transmittance * background[c];
      px[3] = 1.0 - comp.transmittance;
    }
  }
  return img;
}

Camera camera_near_box(std::mt19937_64& rng, const client_core::DAabb& box, double reach,
                       std::uint32_t w, std::uint32_t h) {
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  const DVec3 c = (box.min + box.max) * 0.5;
  const DVec3 ext = box.max - box.min;
  for (;;) {
    const DVec3 eye = c + DVec3{u(rng), u(rng), u(rng)} * reach;
    const DVec3 target = c + DVec3{u(rng) * ext.x, u(rng) * ext.y, u(rng) * ext.z};
    auto cam = Camera::look_at(eye, target, {0, 0, 1}, 60, w, h);
    if (cam.ok()) return *cam;
  }
}

RenderImage render_or_fail(const PoolView& pools, const Camera& cam,
                           const client_core::RenderOptions& opt, client_core::RenderStats* stats) {
  auto img = client_core::render_reference(pools, cam, opt, stats);
  EXPECT_TRUE(img.ok()) << (img.ok() ? "" : img.error().message);
  return img.ok() ? std::move(img).value() : RenderImage{};
}

std::unique_ptr<Octree> clustered_tree(std::uint64_t seed, int depth) {
  auto tree = random_tree(seed, 300, 10);
  for (std::uint32_t c = 0; c < tree->high_water_cells(); ++c) {
    if (tree->is_live(c) && tree->is_leaf(c) && tree->depth(c) < depth) tree->set_colour(c, 0);
  }
  tree->refresh_interior_colours();
  return tree;
}

double max_channel_diff(const RenderImage& a, const RenderImage& b) {
  EXPECT_EQ(a.width, b.width);
  EXPECT_EQ(a.height, b.height);
  double m = 0;
  for (std::size_t i = 0; i < std::min(a.rgba.size(), b.rgba.size()); ++i) {
    m = std::max(m, std::abs(a.rgba[i] - b.rgba[i]));
  }
  return m;
}

}  // namespace deepcanvas::render_test

namespace deepcanvas::render_test {

PrecisionSceneData precision_scene(std::uint32_t width, std::uint32_t height) {
  PrecisionSceneData out;
  auto t = Octree::create({});
  EXPECT_TRUE(t.ok());
  if (!t.ok()) return out;
  out.tree = std::move(t).value();
  Octree& tree = *out.tree;
  const DVec3 eye{9999.9987123, 9999.9981337, 9999.9976543};
  std::vector<DVec3> pts;
  for (int i = -3; i <= 3; ++i) {
    for (int j = -3; j <= 3; ++j) {
      for (int k = -3; k <= 3; ++k) pts.push_back(eye + DVec3{i * 0.3e-3, j * 0.3e-3, k * 0.3e-3});
    }
  }
  refine_around(tree, pts, 24);
  int painted = 0;
  for (std::uint32_t c = 0; c < tree.high_water_cells(); ++c) {
    if (!tree.is_live(c) || !tree.is_leaf(c)) continue;
    const auto co = tree.coord(c);
    if (co.depth != 24) continue;
    std::uint64_t h = (co.x * 0x9E3779B97F4A7C15ull) ^ (co.y * 0xC2B2AE3D27D4EB4Full) ^
                      (co.z * 0x165667B19E3779F9ull);
    h ^= h >> 29;
    h *= 0xBF58476D1CE4E5B9ull;
    h ^= h >> 32;
    if (h % 2 == 0) continue;
    const std::uint32_t a = 60 + static_cast<std::uint32_t>((h >> 8) % 140);
    tree.set_colour(c, (static_cast<std::uint32_t>(h >> 16) & 0xFFFFFFu) | (a << 24));
    ++painted;
  }
  EXPECT_GT(painted, 50);
  tree.recompute_masked_links();
  auto cam = Camera::look_at(eye, eye + DVec3{-1.0, -0.7, -0.45}, {0, 0, 1}, 75, width, height);
  EXPECT_TRUE(cam.ok());
  if (cam.ok()) out.camera = *cam;
  return out;
}

MultiScaleScene multiscale_scene(std::uint64_t seed, std::uint32_t width, std::uint32_t height) {
  MultiScaleScene out;
  auto t = Octree::create({});
  EXPECT_TRUE(t.ok());
  if (!t.ok()) return out;
  out.tree = std::move(t).value();
  Octree& tree = *out.tree;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  // Broad: depth 7 (39 m cells) over a ~400 m ball at (1000, 500, 200).
  const DVec3 big{1000.0, 500.0, 200.0};
  std::vector<DVec3> pts;
  for (int i = 0; i < 150; ++i) pts.push_back(big + DVec3{u(rng), u(rng), u(rng)} * 400.0);
  refine_around(tree, pts, 7);
  // Tiny: depth 20 (4.8 mm cells) over a ~5 cm ball just outside the broad cluster's box.
  const DVec3 small = big + DVec3{260.0, 0.0, 0.0};
  pts.clear();
  for (int i = 0; i < 150; ++i) pts.push_back(small + DVec3{u(rng), u(rng), u(rng)} * 0.05);
  refine_around(tree, pts, 20);
  for (std::uint32_t c = 0; c < tree.high_water_cells(); ++c) {
    if (!tree.is_live(c) || !tree.is_leaf(c)) continue;
    const auto co = tree.coord(c);
    if (co.depth != 7 && co.depth != 20) continue;
    const std::uint64_t v = rng();
    if (v % 3 == 0) continue;
    const std::uint32_t a = 40 + static_cast<std::uint32_t>((v >> 8) % 216);
    tree.set_colour(c, (static_cast<std::uint32_t>(v >> 20) & 0xFFFFFFu) | (a << 24));
  }
  tree.recompute_masked_links();
  auto wide = Camera::look_at(big + DVec3{-900, -1300, 700}, big + DVec3{130, 0, 0}, {0, 0, 1}, 50,
                              width, height);
  auto close =
      Camera::look_at(small + DVec3{-0.05, -0.09, 0.04}, small, {0, 0, 1}, 60, width, height);
  EXPECT_TRUE(wide.ok() && close.ok());
  if (wide.ok()) out.wide = *wide;
  if (close.ok()) out.close = *close;
  return out;
}

std::optional<std::string> painting_path(const std::string& file) {
  const char* dir = std::getenv("DEEPCANVAS_PAINTINGS");
  if (dir == nullptr) return std::nullopt;
  const std::string path = std::string(dir) + "/" + file;
  if (!std::filesystem::is_regular_file(path)) {
    ADD_FAILURE() << "DEEPCANVAS_PAINTINGS=" << dir << " has no " << file;
    return std::nullopt;
  }
  return path;
}

std::size_t paint_apa(Octree& tree, const std::string& path,
                      const paintings::ApaTransform& transform, std::size_t max_strokes) {
  auto painting = paintings::read_apa_file(path, transform);
  EXPECT_TRUE(painting.ok()) << (painting.ok() ? "" : painting.error().message);
  if (!painting.ok()) return 0;
  // Scenes place paintings at any scale (1000x is ~1 km across): the server's stroke extent
  // limit guards a canvas against one client, it is not part of the picture.
  server_core::PainterConfig config;
  config.limits.max_extent_m = 1e9;
  auto painter = server_core::Painter::create(tree, config);
  EXPECT_TRUE(painter.ok());
  if (!painter.ok()) return 0;
  std::size_t applied = 0;
  for (const auto& stroke : painting->strokes) {
    if (applied == max_strokes) break;
    if ((*painter)->apply_stroke(stroke).ok()) ++applied;
  }
  tree.recompute_masked_links();
  return applied;
}

namespace {
std::optional<client_core::DAabb> bounds_of(const Octree& tree) {
  auto b = client_core::painted_bounds(pool_view_of(tree));
  EXPECT_TRUE(b.ok());
  if (!b.ok() || !b->has_value()) return std::nullopt;
  return **b;
}
}  // namespace

PaintingScene painting_scene(const std::string& path, std::size_t max_strokes) {
  PaintingScene out;
  auto t = Octree::create({});
  EXPECT_TRUE(t.ok());
  if (!t.ok()) return out;
  const std::size_t applied = paint_apa(**t, path, {}, max_strokes);
  EXPECT_GT(applied, 0u) << path;
  auto b = bounds_of(**t);
  if (applied == 0 || !b) {
    ADD_FAILURE() << path << ": nothing painted";
    return out;
  }
  out.tree = std::move(t).value();
  out.bounds = *b;
  return out;
}

MultiScalePaintingScene multiscale_painting_scene(const std::string& big_path,
                                                  const std::string& tiny_path, std::uint32_t width,
                                                  std::uint32_t height) {
  MultiScalePaintingScene out;
  auto t = Octree::create({});
  EXPECT_TRUE(t.ok());
  if (!t.ok()) return out;
  Octree& tree = **t;
  paintings::ApaTransform big;
  big.scale = 1000.0;
  big.offset[0] = 1500.0;
  big.offset[1] = -700.0;
  big.offset[2] = 300.0;
  EXPECT_GT(paint_apa(tree, big_path, big, 1000), 0u);
  auto big_box = bounds_of(tree);
  if (!big_box) {
    ADD_FAILURE() << big_path << " at 1000x: nothing painted";
    return out;
  }
  // The tiny painting 20 m beyond the big one's +x side, level with its centre.
  const DVec3 next_to{big_box->max.x + 20.0, (big_box->min.y + big_box->max.y) / 2,
                      (big_box->min.z + big_box->max.z) / 2};
  paintings::ApaTransform tiny;
  tiny.scale = 0.001;
  tiny.offset[0] = next_to.x;
  tiny.offset[1] = next_to.y;
  tiny.offset[2] = next_to.z;
  EXPECT_GT(paint_apa(tree, tiny_path, tiny, 1000), 0u);
  auto all = bounds_of(tree);
  if (!all) return out;
  // The tiny painting's bounds: the painted leaves within 1 m of where it was placed.
  std::optional<client_core::DAabb> tiny_box;
  for (const LeafBox& l : leaf_boxes(tree)) {
    if ((l.colour >> 24) == 0 || length((l.min + l.max) * 0.5 - next_to) > 1.0) continue;
    if (!tiny_box) tiny_box = client_core::DAabb{l.min, l.max};
    tiny_box->min = {std::min(tiny_box->min.x, l.min.x), std::min(tiny_box->min.y, l.min.y),
                     std::min(tiny_box->min.z, l.min.z)};
    tiny_box->max = {std::max(tiny_box->max.x, l.max.x), std::max(tiny_box->max.y, l.max.y),
                     std::max(tiny_box->max.z, l.max.z)};
  }
  if (!tiny_box) {
    ADD_FAILURE() << tiny_path << " at 0.001x: nothing painted";
    return out;
  }
  out.bounds = *all;
  out.big_bounds = *big_box;
  out.tiny_bounds = *tiny_box;
  out.tree = std::move(t).value();
  for (auto cam : {Camera::frame_box(out.bounds, width, height),
                   Camera::frame_box(out.tiny_bounds, width, height, 60.0, {0.5, -0.6, -0.4}),
                   Camera::look_at((big_box->min + big_box->max) * 0.5, next_to, {0, 0, 1}, 70,
                                   width, height)}) {
    EXPECT_TRUE(cam.ok());
    if (cam.ok()) out.cameras.push_back(*cam);
  }
  return out;
}

}  // namespace deepcanvas::render_test
