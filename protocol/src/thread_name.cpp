#include "deepcanvas/protocol/thread_name.hpp"

#include <pthread.h>

#include <cstring>

namespace deepcanvas::protocol {

void set_thread_name(const char* name) noexcept {
  char cut[16] = {};
  std::strncpy(cut, name, sizeof cut - 1);
  (void)pthread_setname_np(pthread_self(), cut);
}

}  // namespace deepcanvas::protocol
