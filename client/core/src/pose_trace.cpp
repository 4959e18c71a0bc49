// Pose traces: reading, writing, interpolating and generating them (pose_trace.hpp).
#include "deepcanvas/client_core/pose_trace.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <random>
#include <sstream>

namespace deepcanvas::client_core {

namespace {

constexpr std::string_view kHeader = "deepcanvas-pose-trace 1";
constexpr double kPi = 3.14159265358979323846;

DVec3 lerp(const DVec3& a, const DVec3& b, double t) {
  return a + (b - a) * t;
}

Error bad_line(std::size_t line, const std::string& what) {
  return make_error(Errc::malformed, "pose trace line " + std::to_string(line) + ": " + what);
}

}  // namespace

PoseSample PoseTrace::at(double t) const noexcept {
  if (samples.empty()) return {};
  if (!(t > samples.front().t_s)) return samples.front();
  if (t >= samples.back().t_s) return samples.back();
  const auto it = std::upper_bound(samples.begin(), samples.end(), t,
                                   [](double v, const PoseSample& s) { return v < s.t_s; });
  const PoseSample& b = *it;
  const PoseSample& a = *(it - 1);
  const double f = (t - a.t_s) / (b.t_s - a.t_s);
  PoseSample s;
  s.t_s = t;
  s.pose.head = lerp(a.pose.head, b.pose.head, f);
  s.pose.orientation = blend(a.pose.orientation, b.pose.orientation, f);
  // The scale geometrically (a grab that scales by 8x looks steady), the origin linearly.
  s.pose.world_scale = a.pose.world_scale * std::pow(b.pose.world_scale / a.pose.world_scale, f);
  s.pose.world_origin = lerp(a.pose.world_origin, b.pose.world_origin, f);
  s.tip = lerp(a.tip, b.tip, f);
  s.trigger = a.trigger + (b.trigger - a.trigger) * f;
  return s;
}

Result<PoseTrace> parse_pose_trace(std::string_view text) {
  PoseTrace out;
  std::size_t line_no = 0;
  bool header = false;
  std::size_t pos = 0;
  while (pos <= text.size()) {
    const std::size_t nl = text.find('\n', pos);
    std::string_view line = text.substr(pos, nl == std::string_view::npos ? text.size() - pos : nl - pos);
    pos = nl == std::string_view::npos ? text.size() + 1 : nl + 1;
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    const auto first = line.find_first_not_of(" \t");
    if (first == std::string_view::npos || line[first] == '#') continue;
    line.remove_prefix(first);
    if (!header) {
      if (line != kHeader)
        return bad_line(line_no, "expected the header '" + std::string(kHeader) + "'");
      header = true;
      continue;
    }
    double v[16];
    int n = 0;
    std::size_t p = 0;
    while (p < line.size()) {
      while (p < line.size() && (line[p] == ' ' || line[p] == '\t')) ++p;
      if (p >= line.size()) break;
      if (n == 16) return bad_line(line_no, "more than 16 numbers");
      const char* b = line.data() + p;
      const char* e = line.data() + line.size();
      auto r = std::from_chars(b, e, v[n]);
      if (r.ec != std::errc() || (r.ptr != e && *r.ptr != ' ' && *r.ptr != '\t'))
        return bad_line(line_no, "field " + std::to_string(n + 1) + " is not a number");
      if (!std::isfinite(v[n])) return bad_line(line_no, "field " + std::to_string(n + 1) + " is not finite");
      p = static_cast<std::size_t>(r.ptr - line.data());
      ++n;
    }
    if (n != 16) return bad_line(line_no, std::to_string(n) + " numbers, expected 16");
    if (out.samples.size() >= kMaxPoseSamples)
      return bad_line(line_no, "more than " + std::to_string(kMaxPoseSamples) + " samples");
    PoseSample s;
    s.t_s = v[0];
    if (s.t_s < 0 || (!out.samples.empty() && !(s.t_s > out.samples.back().t_s)))
      return bad_line(line_no, "time must be >= 0 and increase from line to line");
    s.pose.head = {v[1], v[2], v[3]};
    const double qn = std::sqrt(v[4] * v[4] + v[5] * v[5] + v[6] * v[6] + v[7] * v[7]);
    if (!(qn > 1e-9)) return bad_line(line_no, "the orientation quaternion is zero");
    s.pose.orientation = {v[4] / qn, v[5] / qn, v[6] / qn, v[7] / qn};
    if (!(v[8] > 0) || v[8] > 1e9) return bad_line(line_no, "world scale must be in (0, 1e9]");
    s.pose.world_scale = v[8];
    s.pose.world_origin = {v[9], v[10], v[11]};
    s.tip = {v[12], v[13], v[14]};
    if (v[15] < 0 || v[15] > 1) return bad_line(line_no, "trigger must be in [0, 1]");
    s.trigger = v[15];
    out.samples.push_back(s);
  }
  if (!header) return make_error(Errc::malformed, "pose trace: empty (no header)");
  if (out.samples.empty()) return make_error(Errc::malformed, "pose trace: no samples");
  return out;
}

Result<PoseTrace> read_pose_trace_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return make_error(Errc::not_found, "cannot open pose trace " + path);
  std::ostringstream ss;
  ss << in.rdbuf();
  auto t = parse_pose_trace(ss.str());
  if (!t) return Error{t.error().code, path + ": " + t.error().message};
  return t;
}

std::string format_pose_trace(const PoseTrace& trace) {
  std::string out = std::string(kHeader) +
                    "\n# t  head xyz  orientation wxyz  world_scale  world_origin xyz  tip xyz  "
                    "trigger\n";
  char buf[512];
  for (const auto& s : trace.samples) {
    const auto& p = s.pose;
    std::snprintf(buf, sizeof buf,
                  "%.6f %.6f %.6f %.6f %.9f %.9f %.9f %.9f %.17g %.17g %.17g %.17g %.6f %.6f %.6f "
                  "%.4f\n",
                  s.t_s, p.head.x, p.head.y, p.head.z, p.orientation.w, p.orientation.x,
                  p.orientation.y, p.orientation.z, p.world_scale, p.world_origin.x,
                  p.world_origin.y, p.world_origin.z, s.tip.x, s.tip.y, s.tip.z, s.trigger);
    out += buf;
  }
  return out;
}

PoseTrace generate_pose_trace(const DAabb& content, double seconds, std::uint64_t seed, double hz) {
  PoseTrace trace;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const DVec3 centre = (content.min + content.max) * 0.5;
  const DVec3 ext = content.max - content.min;
  const double size = std::max({ext.x, ext.y, ext.z, 1e-9});
  // The content about 1.5 m across, its centre 1.2 m up and 1 m in front of the room's origin.
  const double base_scale = size / 1.5;
  const DVec3 content_room{0, 1.2, -1.0};
  // Slow head turns (a few phases of different periods), a lean in every ~8 s, strokes of
  // 1-2 s while leaning, and one grab that scales the world 8x around the painted point and back.
  const double p1 = 2 * kPi * (0.07 + 0.02 * u(rng)), p2 = 2 * kPi * (0.13 + 0.03 * u(rng));
  const double ph1 = kPi * u(rng), ph2 = kPi * u(rng);
  const std::size_t n = std::max<std::size_t>(2, static_cast<std::size_t>(seconds * hz) + 1);
  const double grab_at = seconds * 0.55, grab_len = std::min(4.0, seconds * 0.2);
  DVec3 stroke_dir{u(rng), u(rng), u(rng) * 0.3};
  for (std::size_t i = 0; i < n; ++i) {
    const double t = static_cast<double>(i) / hz;
    PoseSample s;
    s.t_s = t;
    const double yaw = 0.35 * std::sin(p1 * t + ph1) + 0.15 * std::sin(p2 * t + ph2);
    const double pitch = -0.15 + 0.1 * std::sin(p2 * 0.7 * t + ph1);
    // Leaning in: 0 .. 1 and back over a 8 s cycle, 3 s of it close to the content.
    const double cycle = std::fmod(t, 8.0);
    const double lean = cycle < 1.5 ? cycle / 1.5 : cycle < 4.5 ? 1.0 : cycle < 6.0 ? (6.0 - cycle) / 1.5 : 0.0;
    s.pose.head = {0.05 * std::sin(p1 * 1.3 * t), 1.65 - 0.25 * lean, -0.55 * lean};
    s.pose.orientation = multiply(axis_angle({0, 1, 0}, yaw), axis_angle({1, 0, 0}, pitch * (1 + lean)));
    // The tip sweeps over the content while leaning in; the trigger is pressed in strokes.
    const double phase = cycle - 1.5;
    const bool painting = lean >= 1.0 && std::fmod(phase, 1.5) < 1.1;
    if (std::fmod(phase, 1.5) < 0.02) stroke_dir = {u(rng), u(rng), u(rng) * 0.3};
    const double w = std::fmod(phase, 1.5);
    s.tip = content_room + DVec3{0.25 * std::sin(1.7 * t), 0.2 * std::cos(1.3 * t), 0.1 * std::sin(t)} +
            stroke_dir * (0.15 * w);
    s.trigger = painting ? std::clamp(0.4 + 0.5 * std::sin(3.0 * w), 0.05, 1.0) : 0.0;
    // The grab: scale up by 8x about the content's centre and back (geometric in time).
    double k = 0;
    if (t > grab_at && t < grab_at + grab_len) k = std::sin(kPi * (t - grab_at) / grab_len);
    const double scale = base_scale / std::pow(8.0, k);
    s.pose.world_scale = scale;
    // Keep the content's centre where it was in the room while the world scales about it.
    s.pose.world_origin = centre - content_room * scale;
    trace.samples.push_back(s);
  }
  return trace;
}

}  // namespace deepcanvas::client_core
