#include "deepcanvas/base/result.hpp"

namespace deepcanvas {

std::string_view errc_name(Errc code) noexcept {
  switch (code) {
    case Errc::ok: return "ok";
    case Errc::invalid_argument: return "invalid_argument";
    case Errc::malformed: return "malformed";
    case Errc::unsupported: return "unsupported";
    case Errc::out_of_memory: return "out_of_memory";
    case Errc::refused: return "refused";
    case Errc::not_found: return "not_found";
    case Errc::limit_exceeded: return "limit_exceeded";
    case Errc::unauthorized: return "unauthorized";
    case Errc::io_error: return "io_error";
    case Errc::internal: return "internal";
  }
  return "unknown";
}

}  // namespace deepcanvas
