// Pose traces: a recorded head and controller motion for headless headset runs
// (`deepcanvas-client watch --stereo --pose-trace FILE`, deepcanvas-bench headset, and the
// scripted input of `deepcanvas-client xr` where a runtime has no controllers).
//
// File format (text, UTF-8, one sample a line, '#' comments and blank lines ignored):
//   deepcanvas-pose-trace 1
//   T  HX HY HZ  QW QX QY QZ  S  OX OY OZ  CX CY CZ  TRIGGER
// T seconds from the start (strictly increasing); H the head in the room (metres); Q its
// orientation (a non-zero quaternion, normalised on reading); S the world scale (> 0) and O the
// world origin in the canvas (stereo.hpp: ArtistPose); C the controller tip in the room and
// TRIGGER its pressure in [0, 1] (0: not painting). Numbers are finite decimals.
//
// Untrusted input: parse_pose_trace checks every field and refuses (malformed, naming the line
// and the field) anything else, and more than kMaxPoseSamples lines.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/client_core/stereo.hpp"

namespace deepcanvas::client_core {

inline constexpr std::size_t kMaxPoseSamples = 10'000'000;  // ~31 h at 90 Hz

struct PoseSample {
  double t_s = 0;
  ArtistPose pose;
  DVec3 tip;           // the controller tip in the room, metres
  double trigger = 0;  // 0..1
};

struct PoseTrace {
  std::vector<PoseSample> samples;  // t strictly increasing
  double duration_s() const noexcept { return samples.empty() ? 0.0 : samples.back().t_s; }
  // The pose at time t: interpolated between the samples around it (positions and scale
  // linearly, the orientation by blend), clamped to the first and last sample. Empty trace: a
  // default sample.
  PoseSample at(double t_s) const noexcept;
};

Result<PoseTrace> parse_pose_trace(std::string_view text);
Result<PoseTrace> read_pose_trace_file(const std::string& path);
std::string format_pose_trace(const PoseTrace& trace);

// A realistic trace for content inside `content` (canvas metres): the artist stands in front
// of the content at a world scale that fits it in about 1.5 m, turns the head to look around
// it, leans in to paint (the controller tip moving over the content with the trigger pressed,
// in strokes of a second or two), scales the world up by 8x around the point painted and back
// (a two-handed grab), at `hz` samples a second. Deterministic for a seed.
PoseTrace generate_pose_trace(const DAabb& content, double seconds, std::uint64_t seed,
                              double hz = 90.0);

}  // namespace deepcanvas::client_core
