// Helpers shared by the painting tests.
#pragma once

#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <memory>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "deepcanvas/protocol/density_model.hpp"
#include "deepcanvas/server_core/octree.hpp"
#include "deepcanvas/server_core/painter.hpp"

namespace deepcanvas::painting_test {

// A fresh octree and a painter on it (creation failures are test failures).
struct Canvas {
  std::unique_ptr<server_core::Octree> tree;
  std::unique_ptr<server_core::Painter> painter;
  explicit Canvas(server_core::PainterConfig pc = {}, server_core::OctreeConfig oc = {}) {
    auto t = server_core::Octree::create(oc);
    EXPECT_TRUE(t) << t.error().message;
    tree = std::move(*t);
    auto p = server_core::Painter::create(*tree, pc);
    EXPECT_TRUE(p) << p.error().message;
    painter = std::move(*p);
  }
};

// A random stroke near the origin (4 mm to 24 cm radius, 1 to 12 samples); with `all_modes`
// paint, erase, recolor or smudge, else paint.
inline protocol::Stroke random_stroke(std::mt19937& rng, bool all_modes) {
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  std::uniform_real_distribution<double> u01(0, 1);
  protocol::Stroke s;
  const int m = all_modes ? static_cast<int>(rng() % 4) : 0;  // paint erase recolor smudge
  s.brush.mode = static_cast<protocol::BrushMode>(m);
  for (float& c : s.brush.colour) c = static_cast<float>(u01(rng));
  s.brush.colour[3] = static_cast<float>(0.3 + 0.7 * u01(rng));
  s.brush.opacity = static_cast<float>(0.2 + 0.8 * u01(rng));
  s.brush.hardness = static_cast<float>(u01(rng));
  const double r = std::exp(std::log(0.004) + u01(rng) * std::log(60.0));  // 4 mm .. 24 cm
  double x = u(rng), y = u(rng), z = u(rng);
  const int n = 1 + static_cast<int>(rng() % 12);
  for (int i = 0; i < n; ++i) {
    protocol::StrokeSample p;
    p.x = x, p.y = y, p.z = z;
    p.radius = static_cast<float>(r);
    p.pressure = static_cast<float>(0.2 + 0.8 * u01(rng));
    s.samples.push_back(p);
    x += 0.6 * r * (u01(rng) - 0.3);
    y += 0.6 * r * (u01(rng) - 0.5);
    z += 0.3 * r * (u01(rng) - 0.5);
  }
  return s;
}

// The folder of real paintings, or nullopt when DEEPCANVAS_PAINTINGS is unset (tests skip).
// A set but missing folder is a failure.
inline std::optional<std::string> paintings_dir() {
  const char* d = std::getenv("DEEPCANVAS_PAINTINGS");
  if (!d || !*d) return std::nullopt;
  EXPECT_TRUE(std::filesystem::is_directory(d)) << "DEEPCANVAS_PAINTINGS=" << d << " is missing";
  return std::string(d);
}

#define DEEPCANVAS_PAINTINGS_OR_SKIP(var)                                               \
  auto var##_opt = ::deepcanvas::painting_test::paintings_dir();                        \
  if (!var##_opt) GTEST_SKIP() << "DEEPCANVAS_PAINTINGS is not set: no real paintings"; \
  ASSERT_TRUE(std::filesystem::is_directory(*var##_opt));                               \
  const std::string var = *var##_opt

// Max per-channel difference (in quanta) between two trees' canvases. Where one tree is finer,
// its subtree is coarsened with the density model to the other's leaf depth first.
inline std::uint32_t subtree_value(const server_core::Octree& t, server_core::CellIndex c) {
  const auto fc = t.first_child(c);
  if (fc == server_core::kNoCell) return t.colour(c);
  std::uint32_t ch[8];
  for (std::uint32_t i = 0; i < 8; ++i) ch[i] = subtree_value(t, fc + i);
  return protocol::density::coarsen_rgba(ch);
}

inline int channel_diff(std::uint32_t a, std::uint32_t b) {
  int m = 0;
  for (int k = 0; k < 4; ++k)
    m = std::max(m, std::abs(static_cast<int>((a >> (8 * k)) & 0xFF) -
                             static_cast<int>((b >> (8 * k)) & 0xFF)));
  return m;
}

inline int max_canvas_diff(const server_core::Octree& a, server_core::CellIndex ca,
                           const server_core::Octree& b, server_core::CellIndex cb) {
  const auto fa = a.first_child(ca), fb = b.first_child(cb);
  if (fa != server_core::kNoCell && fb != server_core::kNoCell) {
    int m = 0;
    for (std::uint32_t i = 0; i < 8; ++i) m = std::max(m, max_canvas_diff(a, fa + i, b, fb + i));
    return m;
  }
  return channel_diff(subtree_value(a, ca), subtree_value(b, cb));
}

inline int max_canvas_diff(const server_core::Octree& a, const server_core::Octree& b) {
  int m = 0;
  for (server_core::CellIndex r = 0; r < a.root_count(); ++r)
    m = std::max(m, max_canvas_diff(a, r, b, r));
  return m;
}

// A small canvas (2 m, 2 roots per axis, 5 levels: 64^3 finest cells) for the reference.
inline server_core::OctreeConfig small_canvas() {
  server_core::OctreeConfig oc;
  oc.roots_per_axis = 2;
  oc.edge_m = 2.0;
  oc.max_depth = 5;
  oc.block_cells = 512;
  return oc;
}

// The canvas at its finest level: every finest cell holds its leaf's colour refined down to it
// (density model), the value the painter gives a cell when it refines.
inline std::vector<std::uint32_t> finest_cells(const server_core::Octree& t) {
  const int D = t.config().max_depth;
  const std::uint32_t n = t.config().roots_per_axis << D;
  std::vector<std::uint32_t> g(std::size_t{n} * n * n);
  struct Item {
    server_core::CellIndex c;
    server_core::CellCoord k;
  };
  std::vector<Item> stack;
  const std::uint32_t r = t.config().roots_per_axis;
  for (std::uint32_t z = 0; z < r; ++z)
    for (std::uint32_t y = 0; y < r; ++y)
      for (std::uint32_t x = 0; x < r; ++x) stack.push_back({x + r * (y + r * z), {0, x, y, z}});
  while (!stack.empty()) {
    const Item it = stack.back();
    stack.pop_back();
    const auto fc = t.first_child(it.c);
    if (fc != server_core::kNoCell) {
      for (std::uint32_t i = 0; i < 8; ++i)
        stack.push_back({fc + i, server_core::child_coord(it.k, i)});
      continue;
    }
    std::uint32_t v = t.colour(it.c);
    for (int d = it.k.depth; d < D; ++d) v = protocol::density::refine_rgba(v);
    const int s = D - it.k.depth;
    const std::uint32_t e = 1u << s;
    for (std::uint32_t z = 0; z < e; ++z)
      for (std::uint32_t y = 0; y < e; ++y)
        for (std::uint32_t x = 0; x < e; ++x)
          g[((it.k.z << s) + z) * std::size_t{n} * n + ((it.k.y << s) + y) * std::size_t{n} +
            (it.k.x << s) + x] = v;
  }
  return g;
}

}  // namespace deepcanvas::painting_test
