#include "generated_scene.hpp"

#include <cmath>
#include <cstdint>

namespace deepcanvas::client_app {

namespace {

constexpr double kPi = 3.14159265358979323846;

struct SceneBuilder {
  std::vector<protocol::Stroke> strokes;
  std::uint32_t clock_ms = 0;

  protocol::Stroke& begin(protocol::BrushMode mode, float r, float g, float b, float a,
                          float hardness = 0.6f, float opacity = 1.0f) {
    protocol::Stroke s;
    s.brush.mode = mode;
    s.brush.colour[0] = r;
    s.brush.colour[1] = g;
    s.brush.colour[2] = b;
    s.brush.colour[3] = a;
    s.brush.hardness = hardness;
    s.brush.opacity = opacity;
    clock_ms += 400;  // the artist moves to the next stroke
    strokes.push_back(std::move(s));
    return strokes.back();
  }
  void sample(protocol::Stroke& s, double x, double y, double z, float radius,
              float pressure = 1.0f) {
    clock_ms += 11;  // ~90 Hz controller
    s.samples.push_back({x, y, z, radius, pressure, clock_ms});
  }
};

}  // namespace

std::vector<protocol::Stroke> generated_scene() {
  SceneBuilder b;
  using M = protocol::BrushMode;

  // Island: concentric rings of broad, soft strokes.
  for (int ring = 0; ring < 6; ++ring) {
    const double rr = 0.1 + 0.18 * ring;
    auto& s = b.begin(M::paint, 0.76f - 0.04f * ring, 0.66f - 0.02f * ring, 0.42f, 0.9f, 0.4f);
    for (int i = 0; i <= 48; ++i) {
      const double t = 2 * kPi * i / 48.0;
      b.sample(s, rr * std::cos(t), -0.05 - 0.015 * ring, rr * std::sin(t), 0.16f, 0.9f);
    }
  }
  // Trunk: a slightly bent column, thinning as it rises.
  {
    auto& s = b.begin(M::paint, 0.42f, 0.27f, 0.14f, 1.0f, 0.8f);
    for (int i = 0; i <= 40; ++i) {
      const double t = i / 40.0;
      b.sample(s, 0.08 * std::sin(t * 2.0), t * 1.1, 0.05 * t * t, 0.07f, 1.0f - 0.5f * float(t));
    }
  }
  // Foliage: loops of green around the top of the trunk.
  for (int k = 0; k < 6; ++k) {
    auto& s = b.begin(M::paint, 0.15f + 0.05f * k, 0.55f + 0.04f * k, 0.18f, 0.85f, 0.5f);
    const double phase = k * kPi / 3.0;
    for (int i = 0; i <= 36; ++i) {
      const double t = 2 * kPi * i / 36.0;
      const double r = 0.28 + 0.05 * std::sin(3 * t + phase);
      b.sample(s, 0.08 + r * std::cos(t + phase) * 0.9, 1.15 + 0.18 * std::sin(t * 2 + phase),
               0.05 + r * std::sin(t + phase) * 0.9, 0.11f, 0.8f);
    }
  }
  // A red ribbon spiralling around the trunk (a thin brush, fine cells).
  {
    auto& s = b.begin(M::paint, 0.85f, 0.1f, 0.12f, 1.0f, 0.9f);
    for (int i = 0; i <= 160; ++i) {
      const double t = i / 160.0;
      const double a = t * 6 * kPi;
      b.sample(s, 0.13 * std::cos(a), 0.05 + 0.9 * t, 0.13 * std::sin(a), 0.015f, 1.0f);
    }
  }
  // A tiny flower at the island's edge: petals painted with a 2 mm brush.
  for (int p = 0; p < 5; ++p) {
    auto& s = b.begin(M::paint, 0.95f, 0.85f, 0.2f, 1.0f, 0.9f);
    const double a0 = 2 * kPi * p / 5.0;
    for (int i = 0; i <= 12; ++i) {
      const double t = i / 12.0;
      const double r = 0.012 * std::sin(kPi * t);
      const double a = a0 + (t - 0.5) * 0.8;
      b.sample(s, 0.6 + r * std::cos(a), 0.02, 0.35 + r * std::sin(a), 0.002f, 1.0f);
    }
  }
  // Erase a notch out of the island's rim, recolour a band of foliage, smudge the trunk's base.
  {
    auto& s = b.begin(M::erase, 0, 0, 0, 1.0f, 0.7f);
    for (int i = 0; i <= 10; ++i) b.sample(s, -1.0 + 0.03 * i, -0.08, -0.2 + 0.04 * i, 0.12f);
  }
  {
    auto& s = b.begin(M::recolor, 0.9f, 0.45f, 0.1f, 1.0f, 0.5f, 0.8f);
    for (int i = 0; i <= 20; ++i) {
      const double t = 2 * kPi * i / 20.0;
      b.sample(s, 0.08 + 0.3 * std::cos(t), 1.3, 0.05 + 0.3 * std::sin(t), 0.08f);
    }
  }
  {
    auto& s = b.begin(M::smudge, 0, 0, 0, 1.0f, 0.5f, 0.7f);
    for (int i = 0; i <= 12; ++i) b.sample(s, 0.0 + 0.02 * i, 0.05, 0.12, 0.06f);
  }
  return b.strokes;
}

}  // namespace deepcanvas::client_app
