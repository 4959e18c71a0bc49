// Numbered PNG frames (render --turntable, timelapse) and the video ffmpeg makes of them.
#pragma once

#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "deepcanvas/base/result.hpp"

namespace deepcanvas::client_app {

// Frame i of the sequence named after `out` (spin.png -> spin_0000.png, spin_0001.png, ...).
inline std::string frame_path(const std::string& out, std::size_t i) {
  const std::filesystem::path p(out);
  char num[16];
  std::snprintf(num, sizeof num, "_%04zu", i);
  return (p.parent_path() / (p.stem().string() + num + p.extension().string())).string();
}

// The ffmpeg input pattern of that sequence (spin_%04d.png).
inline std::string frame_pattern(const std::string& out) {
  const std::filesystem::path p(out);
  return (p.parent_path() / (p.stem().string() + "_%04d" + p.extension().string())).string();
}

// The ffmpeg binary on PATH, or empty.
inline std::string find_ffmpeg() {
  const char* path = std::getenv("PATH");
  std::string dirs = path ? path : "/usr/bin:/bin";
  std::size_t start = 0;
  while (start <= dirs.size()) {
    const std::size_t end = dirs.find(':', start);
    const std::string d = dirs.substr(start, end == std::string::npos ? std::string::npos : end - start);
    const std::string f = (d.empty() ? std::string(".") : d) + "/ffmpeg";
    if (::access(f.c_str(), X_OK) == 0) return f;
    if (end == std::string::npos) break;
    start = end + 1;
  }
  return {};
}

// Encodes the frames of `out` into `video` (H.264 in MP4, or whatever ffmpeg picks for the
// extension) at `fps`. unsupported where ffmpeg is not installed; io_error where it fails.
inline Result<void> make_video(const std::string& out, const std::string& video, double fps) {
  const std::string ffmpeg = find_ffmpeg();
  if (ffmpeg.empty())
    return make_error(Errc::unsupported,
                      "no ffmpeg on PATH to make " + video + " (Debian: apt install ffmpeg); the "
                      "PNG frames are written");
  const std::string rate = std::to_string(fps);
  std::vector<std::string> args = {ffmpeg, "-y", "-loglevel", "error", "-framerate", rate,
                                   "-i", frame_pattern(out), "-vf",
                                   "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-pix_fmt", "yuv420p", video};
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  const pid_t pid = ::fork();
  if (pid < 0) return make_error(Errc::io_error, "cannot start ffmpeg");
  if (pid == 0) {
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  int status = 0;
  if (::waitpid(pid, &status, 0) < 0 || !WIFEXITED(status) || WEXITSTATUS(status) != 0)
    return make_error(Errc::io_error, "ffmpeg could not make " + video);
  return {};
}

}  // namespace deepcanvas::client_app
