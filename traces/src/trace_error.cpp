#include <clastrace/traces/trace_error.h>

namespace clastrace::traces {

const char* trace_error_code_name(TraceErrorCode code) {
    switch (code) {
    case TraceErrorCode::ok: return "ok";
    case TraceErrorCode::io_error: return "io_error";
    case TraceErrorCode::not_a_trace: return "not_a_trace";
    case TraceErrorCode::unsupported_version: return "unsupported_version";
    case TraceErrorCode::truncated: return "truncated";
    case TraceErrorCode::bad_chunk: return "bad_chunk";
    case TraceErrorCode::length_out_of_range: return "length_out_of_range";
    case TraceErrorCode::checksum_mismatch: return "checksum_mismatch";
    case TraceErrorCode::decompress_failed: return "decompress_failed";
    case TraceErrorCode::invalid_record: return "invalid_record";
    case TraceErrorCode::missing_contents: return "missing_contents";
    case TraceErrorCode::content_mismatch: return "content_mismatch";
    case TraceErrorCode::bad_index: return "bad_index";
    case TraceErrorCode::trailing_bytes: return "trailing_bytes";
    case TraceErrorCode::invalid_argument: return "invalid_argument";
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
