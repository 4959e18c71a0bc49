// Names the calling thread for profilers and debuggers (perf --sort comm, top -H, gdb).
// Linux keeps at most 15 characters; longer names are cut. Best effort: never fails.
#pragma once

namespace deepcanvas::base {

void set_thread_name(const char* name) noexcept;

}  // namespace deepcanvas::base
