// Shared by the gpu-label tests: one Vulkan context per test process (lavapipe pipelines are
// slow to create, contexts are not free either).
//
// No device is a test FAILURE: this executable exists to prove the GPU path runs in CI. Only
// DEEPCANVAS_ALLOW_NO_GPU=1 turns it into a skip (for developer machines without any driver).
#pragma once

#include <gtest/gtest.h>

#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>

#include "deepcanvas/client_gpu/context.hpp"

namespace deepcanvas::client_gpu::testing {

struct SharedContext {
  std::unique_ptr<Context> ctx;
  std::string error;
};

inline SharedContext& shared_context() {
  static SharedContext shared = [] {
    SharedContext s;
    auto built = ContextBuilder().app_name("client_gpu_test").build();
    if (built) {
      s.ctx = std::move(*built);
    } else {
      s.error = built.error().message;
    }
    return s;
  }();
  return shared;
}

inline bool allow_no_gpu() {
  const char* v = std::getenv("DEEPCANVAS_ALLOW_NO_GPU");
  return v != nullptr && std::strcmp(v, "1") == 0;
}

}  // namespace deepcanvas::client_gpu::testing

// Puts the shared context in `ctx` (a Context&), or fails / skips the test.
#define DEEPCANVAS_REQUIRE_GPU(ctx_ptr)                                                    \
  do {                                                                                     \
    auto& shared_ = ::deepcanvas::client_gpu::testing::shared_context();                   \
    if (!shared_.ctx) {                                                                    \
      if (::deepcanvas::client_gpu::testing::allow_no_gpu()) {                             \
        GTEST_SKIP() << "no Vulkan device (DEEPCANVAS_ALLOW_NO_GPU=1): " << shared_.error; \
      }                                                                                    \
      FAIL() << "no usable Vulkan device; this test must run on one (lavapipe in CI). "    \
             << shared_.error;                                                             \
    }                                                                                      \
    ctx_ptr = shared_.ctx.get();                                                           \
  } while (0)
