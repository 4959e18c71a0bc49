// Options every networked client command shares: --connect URL, --token, --canvas.
// The canvas name may also be the URL's path (ws://127.0.0.1:7878/NAME).
#pragma once

#include <cstdlib>
#include <string>
#include <string_view>

#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/protocol/result.hpp"

namespace deepcanvas::client_app {

inline constexpr const char* kConnectHelp =
    "  --connect URL      server WebSocket URL, ws://HOST:PORT[/CANVAS] (default\n"
    "                     ws://127.0.0.1:7878/default)\n"
    "  --canvas NAME      canvas name (overrides the URL's path)\n"
    "  --token TOKEN      access token (default: $DEEPCANVAS_TOKEN, else none)\n";

struct ConnectArgs {
  std::string url = "ws://127.0.0.1:7878/default";
  std::string canvas;  // empty: from the URL's path
  std::string token;
};

// Parses one of the shared options at argv[i]; advances i past its value. Returns false when
// argv[i] is not one of them, an error when its value is missing.
inline Result<bool> parse_connect_option(int argc, char** argv, int& i, ConnectArgs& out) {
  const std::string_view a = argv[i];
  std::string* target = nullptr;
  if (a == "--connect") target = &out.url;
  else if (a == "--canvas") target = &out.canvas;
  else if (a == "--token") target = &out.token;
  else return false;
  if (i + 1 >= argc) return make_error(Errc::invalid_argument, std::string(a) + " needs a value");
  *target = argv[++i];
  return true;
}

inline Result<client_core::ClientOptions> client_options(const ConnectArgs& args,
                                                         protocol::Role role,
                                                         std::string client_name) {
  client_core::ClientOptions o;
  const std::string_view url = args.url;
  constexpr std::string_view scheme = "ws://";
  if (url.substr(0, scheme.size()) != scheme)
    return make_error(Errc::invalid_argument, "--connect: expected ws://HOST:PORT[/CANVAS], got '" +
                                                  args.url + "'");
  const auto slash = url.find('/', scheme.size());
  o.url = std::string(url.substr(0, slash)) + "/";
  std::string path = slash == std::string_view::npos ? "" : std::string(url.substr(slash + 1));
  while (!path.empty() && path.back() == '/') path.pop_back();
  o.canvas = !args.canvas.empty() ? args.canvas : (!path.empty() ? path : "default");
  if (!args.token.empty()) {
    o.token = args.token;
  } else if (const char* env = std::getenv("DEEPCANVAS_TOKEN"); env && *env) {
    o.token = env;
  }
  o.role = role;
  o.client_name = std::move(client_name);
  return o;
}

}  // namespace deepcanvas::client_app
