// A quick end-to-end check of a device: one compute dispatch of an embedded shader whose every
// output word the CPU recomputes. Used by `deepcanvas-client devices --check` and usable at
// start-up by any command that wants to fail early on a broken driver. Blocking; thread-safe as
// Context::submit_once.
#pragma once

#include <cstdint>
#include <optional>

#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/base/result.hpp"

namespace deepcanvas::client_gpu {

struct SelfCheckReport {
  std::uint32_t invocations = 0;      // all verified
  std::optional<double> dispatch_ns;  // GPU time of the dispatch, when timestamps exist
};

// Error wrong_result on the first wrong word (the message names it), else the Vulkan errors of
// pipeline creation and submission.
Result<SelfCheckReport> self_check(const Context& ctx, std::uint32_t invocations = 1u << 16);

// The CPU twin of the shader's hash (exposed for the unit test).
std::uint32_t self_check_hash(std::uint32_t x) noexcept;

}  // namespace deepcanvas::client_gpu
