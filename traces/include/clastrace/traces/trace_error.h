// SPDX-License-Identifier: Apache-2.0
// Errors of the trace format: one code per rule broken, the file offset where it was
// found, and a message that names file, offset and problem. No exceptions cross this API.
#pragma once

#include <cstdint>
#include <string>

namespace clastrace::traces {

enum class TraceErrorCode : uint8_t {
    kOk = 0,
    kIoError,             // open/read/write/fsync failed (errno text in the message)
    kNotATrace,           // wrong file magic
    kUnsupportedVersion,  // format major version newer than this reader
    kTruncated,           // the file ends inside a header, chunk or trailer, or has no trailer
    kBadChunk,            // no chunk header where one must be, or chunks missing/out of order
    kLengthOutOfRange,    // a length/count field claims more than the limits or the file allow
    kChecksumMismatch,    // a header, chunk or payload checksum does not match
    kDecompressFailed,    // zstd rejected a payload whose checksum matched (writer bug)
    kInvalidRecord,       // a record fails the FlatBuffers verifier or the framing rules
    kMissingContents,     // a snapshot refers to a content hash never defined before it
    kContentMismatch,  // contents whose bytes do not hash to their key, or snapshot size != contents size
    kBadIndex,         // the index chunk or trailer is damaged or disagrees with the chunks
    kTrailingBytes,    // bytes after the trailer
    kInvalidArgument,  // API misuse (bad options, unknown submission, finished writer)
};

struct TraceError {
    TraceErrorCode code = TraceErrorCode::kOk;
    uint64_t file_offset = 0;  // byte offset in the file the problem was found at
    std::string message;       // "<file>: offset <n>: <problem>"

    explicit operator bool() const { return code != TraceErrorCode::kOk; }
};

// Stable lower-case name of a code ("checksum_mismatch"), used in JSON output.
const char* trace_error_code_name(TraceErrorCode code);

// Builds a TraceError whose message is "<file>: offset <offset>: <problem>".
TraceError make_trace_error(TraceErrorCode code, const std::string& file, uint64_t offset,
                            const std::string& problem);

}  // namespace clastrace::traces
