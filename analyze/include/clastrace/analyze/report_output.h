// What `clastrace analyze TRACE [--json | --html OUT.html]` does once it holds a report:
// render it in the chosen format to a file or standard output.
#pragma once

#include <string>

#include "clastrace/analyze/report.h"

namespace clastrace::analyze {

enum class ReportFormat { text, json, html };

// Writes `report` as `format` to `path`; an empty path or "-" means standard output. Returns
// false, with *error naming the path and the system's reason, when the file cannot be written
// completely (nothing half-written is left behind as if it were a report).
bool write_report(const AnalysisReport& report, ReportFormat format, const std::string& path, std::string* error);

}  // namespace clastrace::analyze
