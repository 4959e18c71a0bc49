// Large canvases for the large and network suites: `deepcanvas-server replay --tile-to-cells`
// of the real paintings, as a stroke log a `serve --playback` server paints in one step.
#pragma once

#include <cstdint>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <sys/types.h>

#include "deepcanvas/base/result.hpp"

namespace deepcanvas::bench {

// Runs `SERVER replay --tile-to-cells N --seed 7 demo.apa dancer.apa --log-out LOG --json` with
// the paintings in `paintings`; returns its JSON (cells, placements, strokes, ...).
Result<nlohmann::json> generate_tiled_log(const std::string& server,
                                          const std::filesystem::path& paintings, std::uint64_t n,
                                          const std::string& log);

// VmRSS of process `pid` (0: this process), bytes; 0 when unreadable.
std::uint64_t rss_bytes(pid_t pid);

}  // namespace deepcanvas::bench
