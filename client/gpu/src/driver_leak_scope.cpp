// Leak checking around the Vulkan driver, in AddressSanitizer builds only.
//
// Why: a Vulkan driver is a shared library the loader dlopen()s and dlclose()s. Mesa point
// releases differ in the few bytes they leave allocated at exit (22.3.6-1+deb12u2's lavapipe
// leaves one 128-byte realloc). By the time LeakSanitizer reports at exit the driver is
// unmapped, so the allocation's stack reads "<unknown module>" and no suppression can name it.
// So, in ASan builds: every library loaded by the time an instance exists is made
// non-unloadable (dlopen RTLD_NOLOAD | RTLD_NODELETE: no new load, only a flag), leak stacks keep
// their module names, and the suppressions below drop leaks whose stack passes through a
// Vulkan driver or the loader. Leaks whose stacks stay in our code are still reported: the
// ctest `asan_leak_in_our_code_is_reported` leaks on purpose next to a live instance and
// requires LeakSanitizer's report.
#include "driver_leak_scope.hpp"

#if defined(__SANITIZE_ADDRESS__)
#define DEEPCANVAS_ASAN_BUILD 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define DEEPCANVAS_ASAN_BUILD 1
#endif
#endif

#ifdef DEEPCANVAS_ASAN_BUILD
#include <dlfcn.h>
#include <link.h>

#include <string>
#include <vector>

// LeakSanitizer reads this hook at start-up (the same syntax as a suppressions file). Each line
// drops a leak with any stack frame in a module whose path contains the text: the Vulkan loader,
// Mesa's drivers (lavapipe, radv, anv, ...; their LLVM), NVIDIA's.
extern "C" const char* __lsan_default_suppressions() {
  return "leak:libvulkan.so\n"
         "leak:libvulkan_\n"
         "leak:libLLVM\n"
         "leak:libnvidia-\n"
         "leak:libGLX_nvidia\n";
}
#endif

namespace deepcanvas::client_gpu::detail {

void keep_drivers_mapped_for_leak_reports() {
#ifdef DEEPCANVAS_ASAN_BUILD
  std::vector<std::string> paths;
  dl_iterate_phdr(
      [](dl_phdr_info* info, std::size_t, void* out) {
        if (info->dlpi_name != nullptr && info->dlpi_name[0] != '\0') {
          static_cast<std::vector<std::string>*>(out)->emplace_back(info->dlpi_name);
        }
        return 0;
      },
      &paths);
  for (const std::string& path : paths) {
    // RTLD_NOLOAD: only objects already loaded; the extra reference is kept on purpose.
    (void)dlopen(path.c_str(), RTLD_NOW | RTLD_NOLOAD | RTLD_NODELETE);
  }
#endif
}

}  // namespace deepcanvas::client_gpu::detail
