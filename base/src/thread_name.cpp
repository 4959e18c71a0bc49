#include "deepcanvas/base/thread_name.hpp"

#include <pthread.h>

#include <cstring>

namespace deepcanvas::base {

void set_thread_name(const char* name) noexcept {
  char cut[16] = {};
  std::strncpy(cut, name, sizeof cut - 1);
  (void)pthread_setname_np(pthread_self(), cut);
}

}  // namespace deepcanvas::base
