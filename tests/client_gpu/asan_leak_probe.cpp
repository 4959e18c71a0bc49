// A probe for the AddressSanitizer stage (built only with DEEPCANVAS_ASAN): it creates and
// destroys a Vulkan device the way every GPU test does, and with --leak also leaks a buffer
// from our own code. ctest requires that the run without --leak is clean (the driver's own
// allocations are not counted as ours) and that the run with --leak is reported by
// LeakSanitizer, naming leak_on_purpose (our leaks still are).
#include <cstdio>
#include <cstring>

#include "deepcanvas/client_gpu/context.hpp"

namespace {

void* volatile g_sink = nullptr;

[[gnu::noinline]] void leak_on_purpose() {
  g_sink = new char[4096];
  g_sink = nullptr;  // the only pointer is gone: a direct leak
}

}  // namespace

int main(int argc, char** argv) {
  const bool leak = argc > 1 && std::strcmp(argv[1], "--leak") == 0;
  {
    auto ctx = deepcanvas::client_gpu::ContextBuilder().build();
    if (!ctx) {
      std::fprintf(stderr, "asan_leak_probe: no Vulkan device: %s\n", ctx.error().message.c_str());
      return 1;
    }
    std::printf("asan_leak_probe: device created and destroyed\n");
  }
  if (leak) leak_on_purpose();
  return 0;
}
