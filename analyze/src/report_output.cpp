// SPDX-License-Identifier: Apache-2.0
#include "clastrace/analyze/report_output.h"

#include <iostream>
#include <sstream>

#include <clastrace/traces/output_file.h>

#include "clastrace/analyze/render.h"

namespace clastrace::analyze {

namespace {

void render(const AnalysisReport& report, ReportFormat format, std::ostream& out) {
    switch (format) {
    case ReportFormat::kText: render_text(report, out); break;
    case ReportFormat::kJson: render_json(report, out); break;
    case ReportFormat::kHtml: render_html(report, out); break;
    }
}

}  // namespace

bool write_report(const AnalysisReport& report, ReportFormat format, const std::string& path,
                  std::string* error) {
    if (path.empty() || path == "-") {
        render(report, format, std::cout);
        std::cout.flush();
        if (!std::cout) {
            if (error) *error = "standard output: write failed";
            return false;
        }
        return true;
    }
    // The output-file rule (traces/output_file.h): a report replaces a regular file only whole,
    // and never replaces a device, FIFO or symbolic link.
    std::ostringstream out;
    render(report, format, out);
    return traces::write_output_file(path, out.view(), error);
}

}  // namespace clastrace::analyze
