// SPDX-License-Identifier: Apache-2.0
// The writer's rule for the strings a trace stores (docs/trace-format.md): UTF-8, whatever
// bytes the application or the caller gave. A schema field of type string is listed here once
// for the packed record and once for the object API, side by side in stored_text.cpp.
#pragma once

#include <clastrace/traces/trace_generated.h>

namespace clastrace::traces {

// Replaces what is not UTF-8 in the header's names, driver texts and extension names.
void make_strings_valid_utf8(fbs::TraceHeaderT& header);

// Whether any string of a verified record is not UTF-8 (most records carry none).
bool has_invalid_utf8(const fbs::Record& record);
void make_strings_valid_utf8(fbs::RecordT& record);

}  // namespace clastrace::traces
