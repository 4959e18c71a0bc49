// The project's own scene, generated: a small island with a tree, a ribbon and a flower, painted
// at several scales (brushes from 0.15 m down to 2 mm) and with every painting mode that changes
// the canvas (paint, erase, recolor, smudge). Deterministic.
#pragma once

#include <vector>

#include "deepcanvas/protocol/stroke.hpp"

namespace deepcanvas::client_app {

std::vector<protocol::Stroke> generated_scene();

}  // namespace deepcanvas::client_app
