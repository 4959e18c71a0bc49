// See driver_leak_scope.cpp: why the Vulkan driver stays mapped in AddressSanitizer builds.
#pragma once

namespace deepcanvas::client_gpu::detail {

// In AddressSanitizer builds, makes every shared library loaded now (the Vulkan loader's drivers
// included) stay mapped until exit, so LeakSanitizer's report names their modules and its
// suppressions apply. Does nothing in other builds. Call after vkCreateInstance; thread-safe.
void keep_drivers_mapped_for_leak_reports();

}  // namespace deepcanvas::client_gpu::detail
