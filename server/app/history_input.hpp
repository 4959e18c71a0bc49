// What the server's offline commands (replay, export) and history playback (serve --playback)
// read a canvas's history from: an A-Painter .apa painting, a stroke log, or a canvas database
// of a data directory, told apart by their first bytes.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_core/octree.hpp"
#include "deepcanvas/server_core/stroke_log.hpp"

namespace deepcanvas::server_app {

// An .apa painting or a stroke log, with the transform its samples are placed by.
struct Input {
  std::string path;
  paintings::ApaTransform tf;
};

// Each sample's position and radius scaled by tf.scale, then moved by tf.offset.
void transform_samples(std::vector<protocol::StrokeSample>& samples, const paintings::ApaTransform& tf);

// A canvas database of a data directory (serve --data): DIR/NAME.canvas, or DIR/NAME for it.
std::optional<std::string> canvas_database(const std::string& path);

// A canvas database's history up to the end of stroke `until` (0: all of it), with its shape.
// Events carry their artist and wall-clock time.
Result<std::vector<server_core::StrokeEvent>> load_history(const std::string& db,
                                                           std::uint64_t until,
                                                           server_core::OctreeConfig& shape);

// An .apa painting or a stroke log as events in painting order: a stroke log's events as
// recorded (a torn or corrupt tail is reported on stderr, prefixed with `command`, and the
// events before it kept), a painting's strokes one after another (each its begin with every
// sample, then its end; ids 1, 2, ...).
Result<std::vector<server_core::StrokeEvent>> load_input(const Input& in,
                                                         const std::string& command);

}  // namespace deepcanvas::server_app
