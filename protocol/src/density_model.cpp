#include "deepcanvas/protocol/density_model.hpp"

#include <algorithm>
#include <array>
#include <cstdlib>

namespace deepcanvas::protocol::density {

namespace {

struct Tables {
  std::array<std::uint8_t, 256> refine{};
  // log(1 - a/255) for the coarsen product (a = 255 is handled apart: infinite sigma).
  std::array<double, 256> log_t{};
  // Optical depth across one cell edge, -log(1 - a/255); a = 255 counts as
  // kOpaqueOpticalDepth (filter_rgba).
  std::array<double, 256> tau{};
};

const Tables& tables() {
  static const Tables t = [] {
    Tables x;
    for (int a = 0; a < 256; ++a) {
      const double v = alpha_at_level_offset(a / 255.0, 1);
      int q = static_cast<int>(std::lround(v * 255.0));
      if (a > 0 && q == 0) q = 1;
      x.refine[a] = static_cast<std::uint8_t>(q);
      x.log_t[a] = a == 255 ? 0.0 : std::log1p(-a / 255.0);
      x.tau[a] = a == 255 ? kOpaqueOpticalDepth : -std::log1p(-a / 255.0);
    }
    return x;
  }();
  return t;
}

}  // namespace

std::uint8_t refine_alpha(std::uint8_t a) noexcept {
  return tables().refine[a];
}

std::uint32_t refine_rgba(std::uint32_t rgba) noexcept {
  Rgba8 c = unpack(rgba);
  c.a = refine_alpha(c.a);
  return pack(c);
}

std::uint32_t filter_rgba(const std::uint32_t ch[8]) noexcept {
  const Tables& t = tables();
  double tau_sum = 0, rgb[3] = {0, 0, 0};
  for (int i = 0; i < 8; ++i) {
    if (ch[i] == 0) continue;
    const Rgba8 c = unpack(ch[i]);
    const double w = t.tau[c.a];
    tau_sum += w;
    rgb[0] += w * c.r;
    rgb[1] += w * c.g;
    rgb[2] += w * c.b;
  }
  if (tau_sum == 0) return 0;
  Rgba8 out;
  // The parent's edge is twice the child's: optical depth 2 * mean(tau) = tau_sum / 4.
  // Never 0 over a painted child: 0 means "nothing below" (an empty subtree), which the ray
  // casters step over whole (client_core::PoolView::filtered_interiors).
  out.a = std::max<std::uint8_t>(1, quantise(1.0 - std::exp(-tau_sum * 0.25)));
  out.r = quantise(rgb[0] / tau_sum / 255.0);
  out.g = quantise(rgb[1] / tau_sum / 255.0);
  out.b = quantise(rgb[2] / tau_sum / 255.0);
  return pack(out);
}

bool uniform(const std::uint32_t ch[8]) noexcept {
  const Rgba8 c0 = unpack(ch[0]);
  int lo[4] = {c0.r, c0.g, c0.b, c0.a}, hi[4] = {c0.r, c0.g, c0.b, c0.a};
  for (int i = 1; i < 8; ++i) {
    const Rgba8 c = unpack(ch[i]);
    const int v[4] = {c.r, c.g, c.b, c.a};
    for (int k = 0; k < 4; ++k) {
      lo[k] = std::min(lo[k], v[k]);
      hi[k] = std::max(hi[k], v[k]);
    }
  }
  for (int k = 0; k < 4; ++k)
    if (hi[k] - lo[k] > kMergeTolerance) return false;
  return true;
}

std::uint32_t coarsen_rgba(const std::uint32_t ch[8]) noexcept {
  const Tables& t = tables();
  bool all_same = true;
  for (int i = 1; i < 8; ++i) all_same = all_same && ch[i] == ch[0];
  if (all_same) {
    // Exact inverse of refine where 8 bits allow: the parent value whose refinement is this
    // child value and whose real-valued coarsening is nearest.
    Rgba8 c = unpack(ch[0]);
    if (c.a == 0 || c.a == 255) return ch[0];
    const double exact = alpha_at_level_offset(c.a / 255.0, -1) * 255.0;
    int best = -1;
    double best_d = 1e9;
    for (int a = 1; a < 256; ++a) {
      if (t.refine[a] != c.a) continue;
      const double d = std::abs(a - exact);
      if (d < best_d) best_d = d, best = a;
    }
    c.a = best >= 0 ? static_cast<std::uint8_t>(best) : quantise(exact / 255.0);
    return pack(c);
  }
  double sum_log = 0, wsum = 0, rgb[3] = {0, 0, 0};
  bool opaque = false;
  for (int i = 0; i < 8; ++i) {
    const Rgba8 c = unpack(ch[i]);
    if (c.a == 255) opaque = true;
    sum_log += t.log_t[c.a];
    const double w = c.a;  // sigma-share weight (alpha; see the header)
    wsum += w;
    rgb[0] += w * c.r;
    rgb[1] += w * c.g;
    rgb[2] += w * c.b;
  }
  if (wsum == 0) return 0;
  Rgba8 out;
  // Any opaque child has infinite sigma, so the mean is infinite too: the parent is opaque.
  out.a = opaque ? 255 : quantise(1.0 - std::exp(sum_log * 0.25));
  if (out.a == 0) return 0;
  out.r = quantise(rgb[0] / wsum / 255.0);
  out.g = quantise(rgb[1] / wsum / 255.0);
  out.b = quantise(rgb[2] / wsum / 255.0);
  return pack(out);
}

std::uint32_t paint_over(std::uint32_t pre, double q, const float rgb[3]) noexcept {
  if (q <= 0) return pre;
  const Rgba8 p = unpack(pre);
  const double ap = p.a / 255.0;
  const double an = 1.0 - (1.0 - ap) * (1.0 - q);
  if (an <= 0) return 0;
  const double keep = ap * (1.0 - q);
  Rgba8 o;
  o.a = quantise(an);
  o.r = quantise((q * rgb[0] + keep * (p.r / 255.0)) / an);
  o.g = quantise((q * rgb[1] + keep * (p.g / 255.0)) / an);
  o.b = quantise((q * rgb[2] + keep * (p.b / 255.0)) / an);
  return pack(o);
}

std::uint32_t erase(std::uint32_t pre, double e) noexcept {
  if (e <= 0) return pre;
  Rgba8 p = unpack(pre);
  if (p.a == 0) return 0;
  const double tau = p.a == 255 ? kOpaqueOpticalDepth : -std::log1p(-p.a / 255.0);
  p.a = quantise(1.0 - std::exp(-tau * (1.0 - std::clamp(e, 0.0, 1.0))));
  return pack(p);
}

std::uint32_t recolor(std::uint32_t pre, double w, const float rgb[3]) noexcept {
  Rgba8 p = unpack(pre);
  if (p.a == 0 || w <= 0) return pre;
  w = std::clamp(w, 0.0, 1.0);
  p.r = quantise((1 - w) * p.r / 255.0 + w * rgb[0]);
  p.g = quantise((1 - w) * p.g / 255.0 + w * rgb[1]);
  p.b = quantise((1 - w) * p.b / 255.0 + w * rgb[2]);
  return pack(p);
}

}  // namespace deepcanvas::protocol::density
