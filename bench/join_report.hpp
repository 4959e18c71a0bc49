// Where a join's first picture spent its time, for the suites that join large canvases (large,
// network): from connect to the first batch resident on the GPU.
#pragma once

#include <chrono>
#include <cstdio>
#include <string>
#include <vector>

#include "deepcanvas/client_gpu/streaming_replica.hpp"

namespace deepcanvas::bench {

// "the first picture (part of the snapshot): committed 0.17 s after connect, taken 0.23 s,
// resident 0.34 s (of which: ...); 101 ms under the GPU lock (mirror ..., grow ..., ...); N
// batches in all".
inline std::string first_picture_text(const std::vector<client_gpu::ResidentBatch>& batches,
                                      client_gpu::SteadyTime connect) {
  if (batches.empty()) return "no batch became resident";
  const auto& b = batches.front();
  const auto s = [&](client_gpu::SteadyTime t) {
    return std::chrono::duration<double>(t - connect).count();
  };
  char buf[512];
  std::snprintf(buf, sizeof buf,
                "the first picture (%s): committed %.2f s after connect, taken %.2f s, resident "
                "%.2f s (of which: textures grown to hold it %.0f ms before it was taken; mirror "
                "rows prepared %.0f ms, rows staged %.0f ms before the lock); %.0f ms under the GPU lock "
                "(mirror %.0f, grow %.0f, upload %.0f, links %.0f, content %.0f + exact %.0f ms), "
                "%llu rows, %llu link groups; %zu batches in all",
                b.partial ? "part of the snapshot" : "the whole snapshot", s(b.committed_at),
                s(b.taken_at), s(b.resident_at), b.room_ms, b.mirror_prepare_ms, b.stage_ms,
                b.gpu_lock_ms, b.mirror_ms, b.grow_ms,
                b.upload_ms, b.links_ms, b.content_ms, b.content_exact_ms,
                static_cast<unsigned long long>(b.rows),
                static_cast<unsigned long long>(b.link_groups), batches.size());
  return buf;
}

}  // namespace deepcanvas::bench
