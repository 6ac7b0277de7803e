// SPDX-License-Identifier: Apache-2.0
// The one rule for every file clastrace writes (reports, traces, the layer's JSON dump), so that
// naming an output never destroys what is at that path:
// - nothing or a regular file: a whole-file output is written beside it and renamed over it (a
//   failed write leaves the earlier file as it was); a trace, written as it grows, is written
//   in place under an exclusive lock (open_output_in_place);
// - a symbolic link: the rule applies to the file the link points to; the link itself stays;
// - a character device or a FIFO: written in place, never removed, replaced or truncated;
// - a directory, a block device, a socket: refused (nothing is opened).
#pragma once

#include <string>
#include <string_view>

namespace clastrace::traces {

enum class OutputKind { kAbsent, kRegular, kCharacterDevice, kFifo };

struct OutputTarget {
    std::string path;  // where the bytes land: the named path with its symbolic links followed
    OutputKind kind = OutputKind::kAbsent;
};

// "regular file", "character device", ... for messages.
const char* output_kind_name(OutputKind kind);

// Follows the symbolic links of `path` without creating anything. False, with *error naming
// the path and the reason, when the rule refuses the path (directory, block device, socket,
// too many links, empty name).
bool resolve_output(const std::string& path, OutputTarget* target, std::string* error);

// Checks, without creating or changing anything, that write_output_file(path) can succeed as
// far as the file system tells in advance: the rule accepts it and it (or, for a file replaced
// by rename, its directory) is writable.
bool probe_output(const std::string& path, std::string* error);

// Writes `bytes` as the whole content of `path` under the rule above. The replacement of a
// regular file keeps its permission bits. False with *error naming the path and the reason;
// a failed write leaves no temporary file behind.
bool write_output_file(const std::string& path, std::string_view bytes, std::string* error);

// For an output written as it grows (a trace), where a killed writer must still leave what it
// wrote at `path`: opens the rule's target for writing in place, without truncating it (a
// regular file is created when absent). A regular file is locked (flock, exclusive) on the
// returned descriptor for as long as it stays open; when another process holds that lock the
// open is refused with *error saying so. Returns the descriptor (close-on-exec) or -1.
// A FIFO without a reader is refused rather than waited for.
int open_output_in_place(const std::string& path, OutputTarget* target, std::string* error);

// Takes `fd` (opened by open_output_in_place, possibly in another process that passed it
// down) as the output for `path`: checks that it is open for writing and refers to the rule's
// target of `path`, holds the lock on it and makes it close-on-exec. -1 with *error otherwise.
int adopt_output(int fd, const std::string& path, OutputTarget* target, std::string* error);

// Empties the regular file open on `fd` (by open_output_in_place or adopt_output for `path`)
// and puts its offset at 0 (the writer starts the new content there); a device or FIFO is left
// as it is. False with *error naming `path`.
bool start_output_in_place(int fd, const std::string& path, std::string* error);

}  // namespace clastrace::traces
