// SPDX-License-Identifier: Apache-2.0
// What `clastrace analyze TRACE [--json | --html OUT.html]` does once it holds a report:
// render it in the chosen format to a file or standard output.
#pragma once

#include <string>

#include "clastrace/analyze/report.h"

namespace clastrace::analyze {

enum class ReportFormat { kText, kJson, kHtml };

// Writes `report` as `format` to `path`; an empty path or "-" means standard output. The file
// follows the output-file rule (clastrace/traces/output_file.h): a regular file is replaced
// whole by rename, a symbolic link's target is written (the link stays), a character device or
// FIFO is written in place, a directory, block device or socket is refused. Returns false, with
// *error naming the path and the reason, when the report cannot be written completely (nothing
// half-written is left behind as if it were a report).
bool write_report(const AnalysisReport& report, ReportFormat format, const std::string& path,
                  std::string* error);

}  // namespace clastrace::analyze
