// The OpenVDB peer (bench/openvdb_peer.hpp) against the real Painter: the same strokes give the
// same colour and density wherever the answer does not depend on which cell centre coverage is
// evaluated at. Points are classified per stroke from the stamp geometry: "inside" a stroke when
// some stamp covers every point within a cell diagonal of it fully (coverage 1 at any centre the
// octree or the grid could use), "outside" when no stamp reaches within a cell diagonal; points
// that are neither for some stroke are skipped. Compared: alpha at our leaf's edge (the peer's
// density converted, 1 - exp(-sigma h)) and RGB where the cell is not nearly transparent.
#include <gtest/gtest.h>

#include <openvdb/openvdb.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_core/octree.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "deepcanvas/server_core/stamp.hpp"
#include "openvdb_peer.hpp"

namespace deepcanvas::bench {
namespace {

using protocol::Brush;
using protocol::BrushMode;
using protocol::Stroke;
using protocol::StrokeSample;
using server_core::CanvasGeometry;
using server_core::Octree;
using server_core::OctreeConfig;
using server_core::Painter;
using server_core::Stamp;
using server_core::Vec3d;

class PaintBench : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { openvdb::initialize(); }
};

enum class Where { inside, outside, ambiguous };

Where classify(const CanvasGeometry& g, const std::vector<Stamp>& stamps, double hardness,
               const Vec3d& p) {
  bool near = false;
  for (const Stamp& s : stamps) {
    const double ax = s.b.x - s.a.x, ay = s.b.y - s.a.y, az = s.b.z - s.a.z;
    const double l2 = ax * ax + ay * ay + az * az;
    double t = 0;
    if (l2 > 0)
      t = std::clamp(((p.x - s.a.x) * ax + (p.y - s.a.y) * ay + (p.z - s.a.z) * az) / l2, 0.0, 1.0);
    const double dx = s.a.x + ax * t - p.x, dy = s.a.y + ay * t - p.y, dz = s.a.z + az * t - p.z;
    const double d = std::sqrt(dx * dx + dy * dy + dz * dz);
    const double r = s.ra + (s.rb - s.ra) * t;
    // The cell containing p at the stamp's depth (the grid) or finer (the octree refines every
    // leaf the stamp touches to that depth) has its centre within half a diagonal of p; the
    // radius change along the stamp bounds how much the local radius moves over that distance.
    const double m =
        0.5 * std::sqrt(3.0) * g.cell_edge(s.depth) * (1 + 1e-9) + std::abs(s.rb - s.ra);
    if (d <= hardness * (r - m) - m) return Where::inside;
    if (d < s.r_max + m) near = true;
  }
  return near ? Where::ambiguous : Where::outside;
}

struct Compared {
  std::size_t inside = 0, outside = 0, skipped = 0;
};

struct Canvas {
  std::unique_ptr<Octree> tree;
  std::unique_ptr<Painter> painter;
  std::unique_ptr<OpenVdbPeer> rgba8, vec4f;
  int voxel_depth = 0;
};

void paint_all(const std::vector<Stroke>& strokes, Canvas& c) {
  const auto geo = CanvasGeometry::of(OctreeConfig{});
  int finest = 0;
  for (const auto& s : strokes) {
    auto st = server_core::stroke_stamps(geo, {}, s);
    ASSERT_TRUE(st.ok());
    for (const auto& x : *st) finest = std::max(finest, x.depth);
  }
  c.voxel_depth = finest;
  auto tree = Octree::create(OctreeConfig{});
  ASSERT_TRUE(tree.ok());
  c.tree = std::move(*tree);
  auto painter = Painter::create(*c.tree);
  ASSERT_TRUE(painter.ok());
  c.painter = std::move(*painter);
  for (auto kind : {VdbValueKind::rgba8, VdbValueKind::vec4f}) {
    VdbPeerConfig cfg;
    cfg.kind = kind;
    cfg.voxel_depth = finest;
    auto p = OpenVdbPeer::create(OctreeConfig{}, cfg);
    ASSERT_TRUE(p.ok()) << p.error().message;
    (kind == VdbValueKind::rgba8 ? c.rgba8 : c.vec4f) = std::move(*p);
  }
  for (const auto& s : strokes) {
    auto r = c.painter->apply_stroke(s);
    ASSERT_TRUE(r.ok()) << r.error().message;
    auto a = c.rgba8->apply_stroke(s);
    ASSERT_TRUE(a.ok()) << a.error().message;
    auto b = c.vec4f->apply_stroke(s);
    ASSERT_TRUE(b.ok()) << b.error().message;
  }
  c.rgba8->prune();
  c.vec4f->prune();
}

// Compares both peers with the octree at `points`; every classified point must agree.
Compared compare(const std::vector<Stroke>& strokes, const Canvas& c,
                 const std::vector<Vec3d>& points) {
  const auto geo = CanvasGeometry::of(OctreeConfig{});
  std::vector<std::vector<Stamp>> stamps;
  for (const auto& s : strokes) stamps.push_back(*server_core::stroke_stamps(geo, {}, s));
  Compared n;
  int failures = 0;
  for (const Vec3d& p : points) {
    bool inside_any = false, ok = true;
    for (std::size_t i = 0; i < strokes.size() && ok; ++i) {
      const Where w = classify(geo, stamps[i], strokes[i].brush.hardness, p);
      ok = w != Where::ambiguous;
      inside_any = inside_any || w == Where::inside;
    }
    if (!ok) {
      ++n.skipped;
      continue;
    }
    ++(inside_any ? n.inside : n.outside);
    auto ours = c.painter->pick(p);
    EXPECT_TRUE(ours.ok());
    if (!ours.ok()) continue;
    for (const OpenVdbPeer* peer : {c.rgba8.get(), c.vec4f.get()}) {
      const bool q8 = peer == c.rgba8.get();
      auto v = peer->sample(p);
      EXPECT_TRUE(v.ok());
      if (!v.ok()) continue;
      const double h = ours->cell_edge_m;
      const double a = std::isinf(v->sigma_per_m) ? 1.0 : -std::expm1(-v->sigma_per_m * h);
      // Our value is within 1/255 of the model at our leaf (plus 1 for a merge); the RGBA8
      // peer's alpha is quantised at the voxel edge, an error that grows by up to the ratio of
      // edges when converted to our (coarser) leaf.
      const double levels = std::max(0, c.voxel_depth - ours->depth);
      const double tol =
          (2.0 + (q8 ? 0.5 * std::ldexp(1.0, static_cast<int>(levels)) : 0.0)) / 255.0;
      bool same = std::abs(a - ours->alpha) <= tol + 1e-9;
      if (ours->alpha > 0.1f && v->alpha > 0.0f)
        for (int k = 0; k < 3; ++k)
          same = same && std::abs(ours->rgb[k] - v->rgb[k]) <= 3.0f / 255.0f + 1e-6f;
      if (!same && failures++ < 10) {
        std::string where;
        for (std::size_t i = 0; i < strokes.size(); ++i) {
          const auto& b = strokes[i].brush;
          where +=
              "\n  stroke " + std::to_string(i) + " " +
              std::string(protocol::brush_mode_name(b.mode)) + " A " + std::to_string(b.colour[3]) +
              " O " + std::to_string(b.opacity) + " r " +
              std::to_string(strokes[i].samples[0].radius) + ": " +
              (classify(geo, stamps[i], b.hardness, p) == Where::inside ? "inside" : "outside");
        }
        ADD_FAILURE() << (q8 ? "rgba8" : "vec4f") << " peer differs at (" << p.x << ", " << p.y
                      << ", " << p.z << ") " << (inside_any ? "inside" : "outside")
                      << ": ours rgba (" << ours->rgb[0] << ", " << ours->rgb[1] << ", "
                      << ours->rgb[2] << ", " << ours->alpha << ") depth " << ours->depth
                      << ", peer (" << v->rgb[0] << ", " << v->rgb[1] << ", " << v->rgb[2]
                      << ") alpha at our edge " << a << " (voxel alpha " << v->alpha
                      << ", voxel depth " << c.voxel_depth << ")" << where;
      }
    }
  }
  EXPECT_EQ(failures, 0);
  return n;
}

Stroke random_stroke(std::mt19937_64& rng, const Vec3d& centre, double span) {
  std::uniform_real_distribution<double> u(-1, 1), u01(0, 1);
  const double radii[] = {0.01, 0.02, 0.04};  // target depths 21, 20, 19: within two levels
  Stroke s;
  const double r = radii[rng() % 3];
  s.brush.colour[0] = static_cast<float>(u01(rng));
  s.brush.colour[1] = static_cast<float>(u01(rng));
  s.brush.colour[2] = static_cast<float>(u01(rng));
  // Translucent paint, A O <= 0.95: cells never become opaque here. (Erasing an opaque cell is
  // not scale-free in the density model: it counts as kOpaqueOpticalDepth per cell edge at the
  // depth it is stored at, and the octree stores merged opaque regions coarser than the grid's
  // voxels. Opaque paint is covered by the sphere and real-painting tests.)
  s.brush.colour[3] = rng() % 2 ? 0.95f : static_cast<float>(0.3 + 0.6 * u01(rng));
  s.brush.opacity = rng() % 2 ? 1.0f : static_cast<float>(0.4 + 0.6 * u01(rng));
  s.brush.hardness = 0.9f;
  Vec3d p{centre.x + span * u(rng), centre.y + span * u(rng), centre.z + span * u(rng)};
  const int n = 2 + static_cast<int>(rng() % 5);
  for (int i = 0; i < n; ++i) {
    StrokeSample x;
    x.x = p.x;
    x.y = p.y;
    x.z = p.z;
    x.radius = static_cast<float>(r);
    x.pressure = 1.0f;
    s.samples.push_back(x);
    p = {p.x + 1.5 * r * u(rng), p.y + 1.5 * r * u(rng), p.z + 1.5 * r * u(rng)};
  }
  return s;
}

std::vector<Vec3d> random_points(std::mt19937_64& rng, const std::vector<Stroke>& strokes,
                                 std::size_t count) {
  Vec3d lo{1e9, 1e9, 1e9}, hi{-1e9, -1e9, -1e9};
  for (const auto& s : strokes)
    for (const auto& x : s.samples) {
      const double r = x.radius * 1.5;
      lo = {std::min(lo.x, x.x - r), std::min(lo.y, x.y - r), std::min(lo.z, x.z - r)};
      hi = {std::max(hi.x, x.x + r), std::max(hi.y, x.y + r), std::max(hi.z, x.z + r)};
    }
  std::uniform_real_distribution<double> u(0, 1), v(-1, 1);
  std::vector<Vec3d> out;
  for (std::size_t i = 0; i < count; ++i)
    out.push_back({lo.x + (hi.x - lo.x) * u(rng), lo.y + (hi.y - lo.y) * u(rng),
                   lo.z + (hi.z - lo.z) * u(rng)});
  // As many again near the strokes' samples (within 1.3 radii), where inside and outside meet.
  std::vector<const StrokeSample*> all;
  for (const auto& s : strokes)
    for (const auto& x : s.samples) all.push_back(&x);
  for (std::size_t i = 0; i < count; ++i) {
    const StrokeSample& x = *all[rng() % all.size()];
    const double r = 1.3 * x.radius * x.pressure;
    out.push_back({x.x + r * v(rng), x.y + r * v(rng), x.z + r * v(rng)});
  }
  // The stroke samples themselves: the centres of the stamps.
  for (const auto& s : strokes)
    for (const auto& x : s.samples) out.push_back({x.x, x.y, x.z});
  return out;
}

// Overlapping strokes of three brush sizes (so the grid holds cubes of 1, 8 and 64 voxels),
// opaque and translucent, straddling the canvas centre where eight octree roots meet, then an
// erase and a recolor stroke over them.
TEST_F(PaintBench, PeerMatchesPainterOnRandomStrokes) {
  Compared total;
  for (std::uint64_t seed = 1; seed <= 4; ++seed) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    std::mt19937_64 rng(seed);
    const Vec3d centre = seed % 2 ? Vec3d{0, 0, 0} : Vec3d{0.7, 1.3, -0.4};
    std::vector<Stroke> strokes;
    for (int i = 0; i < 4; ++i) strokes.push_back(random_stroke(rng, centre, 0.05));
    Stroke e = random_stroke(rng, centre, 0.03);
    e.brush.mode = BrushMode::erase;
    e.brush.opacity = 0.6f;
    strokes.push_back(e);
    Stroke rc = random_stroke(rng, centre, 0.03);
    rc.brush.mode = BrushMode::recolor;
    rc.brush.opacity = 0.5f;
    strokes.push_back(rc);
    Canvas c;
    paint_all(strokes, c);
    if (HasFatalFailure()) return;
    EXPECT_GT(c.rgba8->memory().active_voxels, 0u);
    const Compared n = compare(strokes, c, random_points(rng, strokes, 4000));
    total.inside += n.inside;
    total.outside += n.outside;
    total.skipped += n.skipped;
  }
  // The comparison must not be vacuous: plenty of points on both sides of the stroke surfaces.
  EXPECT_GT(total.inside, 1000u);
  EXPECT_GT(total.outside, 1000u);
}

// A single one-sample stroke is a sphere: exactly the voxels whose centre it covers are painted
// (a brute-force count), opaque inside, empty outside.
TEST_F(PaintBench, SphereVolumeMatchesRasterizer) {
  Stroke s;
  StrokeSample x;
  x.x = 0.31;
  x.y = -0.12;
  x.z = 0.05;
  x.radius = 0.02f;
  s.samples.push_back(x);
  s.brush.hardness = 1.0f;  // hard edge: painted voxels are exactly those covered
  Canvas c;
  paint_all({s}, c);
  if (HasFatalFailure()) return;
  // Brute force: voxels (cells at the stamp's depth) whose centre lies inside the sphere.
  const auto geo = CanvasGeometry::of(OctreeConfig{});
  const double h = c.rgba8->voxel_edge_m();
  ASSERT_EQ(h, geo.cell_edge(c.voxel_depth));
  std::uint64_t expected = 0;
  const double half = geo.edge_m * 0.5;
  const auto i0 = static_cast<std::int64_t>(std::floor((x.x - 0.03 + half) / h));
  const auto j0 = static_cast<std::int64_t>(std::floor((x.y - 0.03 + half) / h));
  const auto k0 = static_cast<std::int64_t>(std::floor((x.z - 0.03 + half) / h));
  const int n = static_cast<int>(0.06 / h) + 2;
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        const double cx = -half + (double(i0 + i) + 0.5) * h - x.x;
        const double cy = -half + (double(j0 + j) + 0.5) * h - x.y;
        const double cz = -half + (double(k0 + k) + 0.5) * h - x.z;
        expected += cx * cx + cy * cy + cz * cz < 0.02 * 0.02;
      }
  EXPECT_GT(expected, 100u);
  EXPECT_EQ(c.rgba8->memory().active_voxels, expected);
  EXPECT_EQ(c.rgba8->memory().active_voxels, c.vec4f->memory().active_voxels);
  auto in = c.rgba8->sample({0.31, -0.12, 0.05});
  ASSERT_TRUE(in.ok());
  EXPECT_FLOAT_EQ(in->alpha, 1.0f);
  auto out = c.rgba8->sample({0.31, -0.12, 0.05 + 0.025});
  ASSERT_TRUE(out.ok());
  EXPECT_FLOAT_EQ(out->alpha, 0.0f);
}

TEST_F(PaintBench, RejectsBadInputAndChangesNothing) {
  VdbPeerConfig cfg;
  cfg.voxel_depth = 25;
  EXPECT_EQ(OpenVdbPeer::create(OctreeConfig{}, cfg).error().code, Errc::invalid_argument);
  cfg.voxel_depth = 20;
  auto p = OpenVdbPeer::create(OctreeConfig{}, cfg);
  ASSERT_TRUE(p.ok());
  OpenVdbPeer& peer = **p;
  const auto before = peer.memory().mem_usage;
  Stroke bad;
  StrokeSample x;
  x.radius = 0.01f;
  bad.samples = {x, x};
  bad.samples[1].y = NAN;
  EXPECT_EQ(peer.apply_stroke(bad).error().code, Errc::invalid_argument);
  bad.samples[1].y = 1e6;  // outside the canvas
  EXPECT_EQ(peer.apply_stroke(bad).error().code, Errc::invalid_argument);
  Stroke smudge;
  smudge.brush.mode = BrushMode::smudge;
  smudge.samples = {x};
  EXPECT_EQ(peer.apply_stroke(smudge).error().code, Errc::unsupported);
  Stroke fine;  // a stamp finer than the voxel depth
  x.radius = 0.0005f;
  fine.samples = {x};
  EXPECT_EQ(peer.apply_stroke(fine).error().code, Errc::invalid_argument);
  EXPECT_EQ(peer.memory().active_voxels, 0u);
  EXPECT_EQ(peer.memory().mem_usage, before);
  EXPECT_EQ(peer.sample({2e4, 0, 0}).error().code, Errc::invalid_argument);
}

// A real painting (the smallest, mozilla.apa) at its natural scale: every stroke sample
// position that is clearly inside or outside every stroke agrees.
TEST_F(PaintBench, RealPaintingAgrees) {
  const char* dir = std::getenv("DEEPCANVAS_PAINTINGS");
  if (!dir || !*dir) GTEST_SKIP() << "DEEPCANVAS_PAINTINGS is not set: no real paintings";
  ASSERT_TRUE(std::filesystem::is_directory(dir)) << "DEEPCANVAS_PAINTINGS=" << dir;
  auto painting =
      paintings::read_apa_file(std::string(dir) + "/mozilla.apa", paintings::ApaTransform{});
  ASSERT_TRUE(painting.ok()) << painting.error().message;
  Canvas c;
  paint_all(painting->strokes, c);
  if (HasFatalFailure()) return;
  std::mt19937_64 rng(7);
  const Compared n = compare(painting->strokes, c, random_points(rng, painting->strokes, 3000));
  EXPECT_GT(n.inside, 300u);
  EXPECT_GT(n.outside, 300u);
}

}  // namespace
}  // namespace deepcanvas::bench
