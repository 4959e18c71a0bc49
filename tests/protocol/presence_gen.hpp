// Random presence messages (PROTOCOL.md 3.9) for the property tests: every field drawn over its
// whole valid range, with the edges (0, 1, the canvas boundary) often.
#pragma once

#include <cstdint>
#include <random>
#include <string>

#include "deepcanvas/protocol/messages.hpp"

namespace deepcanvas::test {

inline protocol::Presence random_presence(std::mt19937_64& rng, double half_edge = 10000.0) {
  auto real = [&](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  auto unit = [&]() -> float {
    switch (rng() % 4) {
      case 0:
        return 0.0f;
      case 1:
        return 1.0f;
      default:
        return static_cast<float>(real(0, 1));
    }
  };
  protocol::Presence p;
  p.cursor_on_canvas = rng() % 4 != 0;
  if (p.cursor_on_canvas)
    for (auto& c : p.cursor) c = rng() % 8 == 0 ? half_edge : real(-half_edge, half_edge);
  for (auto& c : p.eye) c = real(-3 * half_edge, 3 * half_edge);
  for (int i = 0; i < 3; ++i) p.target[i] = p.eye[i] + real(-100, 100);
  p.target[rng() % 3] += 1e-3;  // never equal to the eye
  p.vfov_deg = rng() % 5 == 0 ? 178.99 : real(0.01, 178.9);
  for (auto& c : p.colour) c = unit();
  p.size_m = rng() % 5 == 0 ? 0.0 : real(0, 50);
  p.mode = static_cast<protocol::BrushMode>(rng() % protocol::kBrushModeCount);
  p.painting = rng() % 2;
  return p;
}

inline protocol::PresenceUpdate random_presence_update(std::mt19937_64& rng,
                                                       double half_edge = 10000.0) {
  protocol::PresenceUpdate u;
  u.artist = rng() % 3 == 0 ? protocol::kMaxJsonInteger : rng() % 100000;
  static const char* kNames[] = {"", "ann", "studio \"b\" é", "x\ny"};
  u.name = kNames[rng() % 4];
  u.gone = rng() % 4 == 0;
  if (!u.gone) u.presence = random_presence(rng, half_edge);
  return u;
}

}  // namespace deepcanvas::test
