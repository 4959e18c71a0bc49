// Files in and out of a running server: imports converted in a child process (import_worker.cpp
// has why and the protocol), what `serve` sets as ServerConfig::import_cells; and exports written
// for a client, ServerConfig::export_canvas.
#pragma once

#include <chrono>
#include <cstdint>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/protocol/messages.hpp"
#include "deepcanvas/server_core/cell_paste.hpp"
#include "deepcanvas/server_core/octree.hpp"

namespace deepcanvas::server_app {

struct ImportWorkerLimits {
  std::uint64_t memory_bytes = std::uint64_t{8} << 30;     // the worker's address space
  std::chrono::milliseconds timeout{120000};               // killed past this
  std::uint64_t max_reply_bytes = std::uint64_t{256} << 20;  // encoded cells read back at most
};

// Runs `deepcanvas-server import-worker` (this executable) on the import's file. Errors: the
// importer's (exporting::import_cells), malformed where the worker crashed or answered nonsense,
// limit_exceeded past the deadline, io_error where it could not be started.
Result<server_core::CellPaste> import_in_worker(const protocol::Import& m,
                                                const server_core::OctreeConfig& canvas,
                                                const ImportWorkerLimits& limits = {});

// Writes the canvas `tree` as `request` asks (the export target's writers, through a temporary
// file), at most `max_bytes`: limit_exceeded, naming the estimate, before anything is written.
Result<std::vector<std::uint8_t>> export_for_client(const server_core::Octree& tree,
                                                    const protocol::ExportRequest& request,
                                                    std::uint64_t max_bytes);

}  // namespace deepcanvas::server_app
