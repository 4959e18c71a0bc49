// The GPU ray caster: raycast.comp over a GpuReplica, one ray per pixel, the same
// cell-local algorithm as client_core's reference renderer (its Precision::float32 variant is
// this arithmetic on the CPU). Output: RGBA8 per pixel (r in the low byte), row 0 at the top, the
// colour composited over the background and alpha = 1 - transmittance.
//
// The camera is located on the CPU replica in double (client_core::make_ray_origin) and handed
// over as (cell, position in the cell's frame) floats, so precision does not depend on where
// the camera is or how small its cell is.
//
// Frames can be cut into row bands (render_rows), each its own short submission, so uploads and
// G3 dispatches slot in between on a single-queue device (lavapipe).
//
// Scheduling: a dispatch's pixels are work items of kRaycastTilesPerItem 8x8 tiles
// (raycast.comp "Scheduling"), each taken from a counter by whichever subgroup is free, so every
// worker keeps working until the dispatch is done. Why: lavapipe hands each of its worker
// threads an equal contiguous share of a dispatch's workgroups, so with a fixed workgroup per
// tile the thread holding a band's costlier rows finishes last while the others idle, and a
// thread that loses its CPU for a few ms holds the band up by as long. Each band is an items
// pass and a retry pass (an indirect dispatch, empty unless lavapipe's loop limiter cut a
// subgroup short: raycast.comp "Loop limiter"), per up to kRaycastMaxItemsPerDispatch items.
// The price is the item loop's bookkeeping: a whole frame in one dispatch, where no worker waits
// for another, takes somewhat more CPU, while the render loop's banded frames, and its frames
// while a painting streams in, are faster (deepcanvas-bench render; --frames-only for the
// static frames alone). A GPU takes one subgroup per item too; there (an H200) a frame's device
// time hardly grows with its pixels (1.33 ms at 640x360, 1.45 ms at 1280x720): the slowest rays
// set it.
//
// Threading: one thread at a time; the GpuReplica must not be changed during a call, and must
// outlive the raycaster.
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "deepcanvas/client_core/camera.hpp"
#include "deepcanvas/client_core/reference_renderer.hpp"
#include "deepcanvas/client_gpu/compute.hpp"
#include "deepcanvas/client_gpu/replica_gpu.hpp"
#include "deepcanvas/base/result.hpp"

namespace deepcanvas::client_gpu {

struct FrameTiming {
  double gpu_ms = -1;  // timestamps around the dispatches, -1 when unsupported
  double wall_ms = 0;  // record + submit + wait, host clock
  // Work items given up by the items pass and rendered by the retry pass (raycast.comp "Loop
  // limiter"; 0 on a GPU).
  std::uint32_t retried_items = 0;
};

class GpuRaycaster {
 public:
  // Builds both pipelines (G3 stepping and descent from the root).
  static Result<std::unique_ptr<GpuRaycaster>> create(GpuReplica& replica);
  ~GpuRaycaster();
  GpuRaycaster(const GpuRaycaster&) = delete;
  GpuRaycaster& operator=(const GpuRaycaster&) = delete;

  // Sets the frame: camera, its located origin (make_ray_origin on the same pools the replica
  // holds) and options (background, termination, max steps, stepping, content_bounds; precision
  // is float). Pass content_bounds (client_core::painted_bounds of the replica's pools, or any
  // box containing it): rays then skip everything outside it, which is most of a framed
  // painting's steps, with the same image (deepcanvas-bench render reports frames with and
  // without it: *_nocull). bad_argument for bad termination, max steps or bounds.
  Result<void> set_frame(const client_core::Camera& camera, const client_core::RayOrigin& origin,
                         const client_core::RenderOptions& options);
  // Renders rows [row0, row0 + rows) of the frame set last into the output buffer.
  Result<void> render_rows(std::uint32_t row0, std::uint32_t rows, FrameTiming* timing = nullptr);
  // The whole frame in `bands` submissions (1 = one dispatch).
  Result<void> render(std::uint32_t bands = 1, FrameTiming* timing = nullptr);
  // The whole frames of several raycasters of one device (a headset's two eyes), each set by
  // its own set_frame, in one submission with their passes side by side: a GPU runs them at
  // once and the frame pays one submit and one wait (deepcanvas-bench headset compares it with
  // a submission per eye). `timing` covers them all; its GPU time is the first one's timestamps.
  static Result<void> render_together(std::span<GpuRaycaster* const> views,
                                      FrameTiming* timing = nullptr);
  // A subgroup's loop budget (raycast.comp "Loop limiter"; the image does not depend on it):
  // 0 = the default (65000 on a CPU device, none on a GPU). Tests pass 1 (every subgroup takes
  // one item) and ~0u (subgroups take items until lavapipe's limiter stops them, and the retry
  // pass must render what they gave up).
  void set_loop_budget(std::uint32_t n) noexcept;
  // Items the retry pass rendered since create() (tests, benchmarks).
  std::uint64_t retried_items() const noexcept { return retried_items_; }
  // The device is a CPU implementation (lavapipe): its work runs on the host's cores.
  bool cpu_device() const noexcept { return cpu_device_; }
  // The last frame's pixels, width * height RGBA8 words (copied back from the device).
  Result<std::vector<std::uint32_t>> read_pixels() const;
  // The device-local buffer the frames are written to (width * height RGBA8 words of the
  // camera set last; usable as a transfer source), for presenting them without a copy back.
  const Buffer& output() const noexcept { return output_; }
  // Convenience: set_frame + render + pixels as bytes (r, g, b, a per pixel).
  Result<std::vector<std::uint8_t>> render_rgba8(const client_core::Camera& camera,
                                                 const client_core::RayOrigin& origin,
                                                 const client_core::RenderOptions& options);

 private:
  explicit GpuRaycaster(GpuReplica& replica) : replica_(&replica) {}
  Result<void> refresh_descriptors();
  struct Band {
    GpuRaycaster* raycaster;
    std::uint32_t row0, rows;
  };
  static Result<void> render_bands(std::span<const Band> bands, FrameTiming* timing);

  GpuReplica* replica_;
  // [0] G3 items pass, [1] G3 retry pass, [2] descent items pass, [3] descent retry pass, each
  // with its descriptor set.
  static constexpr int kPipelines = 4;
  ComputePipeline pipes_[kPipelines];
  DescriptorPool pool_;
  VkDescriptorSet set_[kPipelines] = {};
  std::uint64_t generation_seen_ = ~std::uint64_t{0};
  Buffer params_;
  Buffer output_;    // device-local, written by the shader
  Buffer readback_;  // host-visible copy for read_pixels()
  // raycast.comp's work regions, one per dispatch of a band (raycast_layout.h), device-local;
  // each region's retry count (kRaycastWorkRetryGroups) is copied to retry_counts_ for the host.
  Buffer work_;
  Buffer retry_counts_;
  std::uint32_t rows_per_dispatch_ = 8;  // set_frame(): items per dispatch within the limit
  bool cpu_device_ = false;
  std::uint32_t subgroups_per_workgroup_ = 1;
  std::uint32_t loop_budget_ = ~0u;
  std::uint64_t retried_items_ = 0;
  std::uint32_t width_ = 0, height_ = 0;
  int pipe_index_ = 0;  // the items pass of the stepping set_frame() chose (0 or 2); + 1: retry
  std::unique_ptr<TimestampQueries> timestamps_;
};

}  // namespace deepcanvas::client_gpu
