// SPDX-License-Identifier: Apache-2.0
#include <clastrace/traces/trace_error.h>

namespace clastrace::traces {

const char* trace_error_code_name(TraceErrorCode code) {
    switch (code) {
    case TraceErrorCode::kOk: return "ok";
    case TraceErrorCode::kIoError: return "io_error";
    case TraceErrorCode::kNotATrace: return "not_a_trace";
    case TraceErrorCode::kUnsupportedVersion: return "unsupported_version";
    case TraceErrorCode::kTruncated: return "truncated";
    case TraceErrorCode::kBadChunk: return "bad_chunk";
    case TraceErrorCode::kLengthOutOfRange: return "length_out_of_range";
    case TraceErrorCode::kChecksumMismatch: return "checksum_mismatch";
    case TraceErrorCode::kDecompressFailed: return "decompress_failed";
    case TraceErrorCode::kInvalidRecord: return "invalid_record";
    case TraceErrorCode::kMissingContents: return "missing_contents";
    case TraceErrorCode::kContentMismatch: return "content_mismatch";
    case TraceErrorCode::kBadIndex: return "bad_index";
    case TraceErrorCode::kTrailingBytes: return "trailing_bytes";
    case TraceErrorCode::kInvalidArgument: return "invalid_argument";
    }
    return "unknown";
}

TraceError make_trace_error(TraceErrorCode code, const std::string& file, uint64_t offset,
                            const std::string& problem) {
    TraceError e;
    e.code = code;
    e.file_offset = offset;
    e.message = file + ": offset " + std::to_string(offset) + ": " + problem;
    return e;
}

}  // namespace clastrace::traces
