#include "clastrace/capture/capture_sink.h"

#include <cerrno>
#include <cstdio>
#include <cstring>

namespace clastrace::capture {

std::unique_ptr<CaptureSink> makeTraceCaptureSink(const std::string& path, int /*zstdLevel*/, std::string& error) {
  // The writability check comes first so an unusable path is reported as such.
  std::FILE* probe = std::fopen(path.c_str(), "wb");
  if (!probe) {
    error = "cannot write '" + path + "': " + std::strerror(errno);
    return nullptr;
  }
  std::fclose(probe);
  std::remove(path.c_str());
  // The trace writer (branch `traces`) is not merged into this branch yet.
  error = "this build cannot write .clt traces yet (the trace writer is not merged); '" + path + "' was not written";
  return nullptr;
}

}  // namespace clastrace::capture
