// --camera and --up, shared by render and watch.
//
// Canvas coordinates are right-handed metres, and A-Painter paintings keep their own axes in the
// canvas (protocol/src/apa.cpp copies x, y, z): +y is up and a painting faces +z, the side its
// artist stood on. So --up defaults to +y, the same up as the framing without --camera (from
// the front, slightly above), and a camera "in front, slightly above" renders upright.
#pragma once

#include <cstdio>
#include <numbers>
#include <string>
#include <string_view>
#include <vector>

#include "cli_options.hpp"
#include "deepcanvas/client_core/camera.hpp"

namespace deepcanvas::client_app {

inline constexpr double kDefaultFovDeg = 45.0;

struct CameraArgs {
  std::string spec;  // EX,EY,EZ,TX,TY,TZ[,FOV]; empty: frame the painted content
  std::string up = "+y";
};

struct CameraSpec {
  client_core::DVec3 eye, target;
  double fov_deg = kDefaultFovDeg;
};

// "EX,EY,EZ,TX,TY,TZ[,FOV]": finite numbers, eye != target, FOV in (0, 179).
inline Result<CameraSpec> parse_camera_spec(std::string_view s) {
  std::vector<double> v;
  for (;;) {
    const auto comma = s.find(',');
    const auto x = parse_number(s.substr(0, comma));
    if (!x)
      return make_error(Errc::invalid_argument,
                        "'" + std::string(s.substr(0, comma)) +
                            "' is not a number (expected EX,EY,EZ,TX,TY,TZ[,FOV])");
    v.push_back(*x);
    if (comma == std::string_view::npos) break;
    s.remove_prefix(comma + 1);
  }
  if (v.size() != 6 && v.size() != 7)
    return make_error(Errc::invalid_argument,
                      "expected 6 or 7 numbers EX,EY,EZ,TX,TY,TZ[,FOV], got " +
                          std::to_string(v.size()));
  CameraSpec c{{v[0], v[1], v[2]}, {v[3], v[4], v[5]}, v.size() == 7 ? v[6] : kDefaultFovDeg};
  if (c.eye == c.target) return make_error(Errc::invalid_argument, "eye and target coincide");
  if (!(c.fov_deg > 0 && c.fov_deg < 179))
    return make_error(Errc::invalid_argument, "FOV must be in (0, 179) degrees");
  return c;
}

// "+x", "-x", "x" (= "+x"), and likewise y and z.
inline Result<client_core::DVec3> parse_up(std::string_view s) {
  double sign = 1;
  if (!s.empty() && (s.front() == '+' || s.front() == '-')) {
    sign = s.front() == '-' ? -1 : 1;
    s.remove_prefix(1);
  }
  if (s == "x") return client_core::DVec3{sign, 0, 0};
  if (s == "y") return client_core::DVec3{0, sign, 0};
  if (s == "z") return client_core::DVec3{0, 0, sign};
  return make_error(Errc::invalid_argument, "expected +x, -x, +y, -y, +z or -z");
}

inline void add_camera_options(CLI::App& app, CameraArgs& args, const std::string& default_view) {
  app.add_option("--camera", args.spec,
                 "eye and target in canvas metres (right-handed axes), then the vertical field "
                 "of view in degrees (default 45); the image's up is --up (default +y: A-Painter "
                 "paintings are y-up and face +z). Default: " +
                     default_view)
      ->type_name("EX,EY,EZ,TX,TY,TZ[,FOV]")
      ->check(CLI::Validator(
          [](std::string& s) -> std::string {
            auto c = parse_camera_spec(s);
            return c ? std::string() : c.error().message;
          },
          ""));
  app.add_option("--up", args.up,
                 "the axis that points up in the image of --camera (default +y, the paintings' "
                 "up)")
      ->type_name("+x|-x|+y|-y|+z|-z")
      ->check(CLI::Validator(
          [](std::string& s) -> std::string {
            auto u = parse_up(s);
            return u ? std::string() : u.error().message;
          },
          ""));
}

// The camera --camera and --up describe (both checked when parsed). invalid_argument when the
// view runs along the up axis: no up is then defined, another --up is needed.
inline Result<client_core::Camera> make_camera(const CameraArgs& args, std::uint32_t width,
                                               std::uint32_t height) {
  const auto spec = parse_camera_spec(args.spec);
  const auto up = parse_up(args.up);
  if (!spec || !up) return make_error(Errc::invalid_argument, "bad --camera or --up");
  const client_core::DVec3 view = spec->target - spec->eye;
  if (client_core::length(client_core::cross(view * (1.0 / client_core::length(view)), *up)) <
      1e-3)
    return make_error(Errc::invalid_argument,
                      "--camera looks along the up axis (--up " + args.up +
                          "): give another --up, e.g. --up " + (args.up.back() == 'z' ? "+y" : "-z"));
  return client_core::Camera::look_at(spec->eye, spec->target, *up, spec->fov_deg, width,
                                      height);
}

// "--camera EX,EY,EZ,TX,TY,TZ,FOV --up UP": `camera` in the form --camera accepts, so that a
// chosen camera can be pasted back. `target` is any point ahead of the camera on its view ray;
// `up` the up axis the camera was made with (its up lies in the plane of that axis and the view).
inline std::string camera_arguments(const client_core::Camera& camera,
                                    const client_core::DVec3& target, const std::string& up) {
  const auto& e = camera.position();
  char buf[320];
  std::snprintf(buf, sizeof buf, "--camera %.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g --up %s", e.x, e.y,
                e.z, target.x, target.y, target.z, camera.vfov_rad() * 180.0 / std::numbers::pi,
                up.c_str());
  return buf;
}

}  // namespace deepcanvas::client_app
