// SPDX-License-Identifier: Apache-2.0
// A .clt file laid out as TraceWriter lays it out (chunks, index, trailer) but with the header
// and records stored exactly as given: what an older or foreign writer leaves, whose strings
// need not be UTF-8. TraceWriter itself repairs them (stored_text.h), so tests that need such
// bytes in a trace write it with this.
#pragma once

#include <clastrace/traces/trace_generated.h>

#include <cstdint>
#include <string>
#include <vector>

namespace clastrace::traces::testing {

// `records` in file order, MemoryContents included (their keys as in the trace they came from).
// Chunks are sealed at header.capture->chunk_raw_bytes, as the writer does.
void write_unrepaired_trace(const std::string& path, const fbs::TraceHeaderT& header,
                            const std::vector<fbs::RecordT>& records);

}  // namespace clastrace::traces::testing
