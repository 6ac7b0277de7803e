#include "clastrace/analyze/report_output.h"

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iostream>

#include "clastrace/analyze/render.h"

namespace clastrace::analyze {

namespace {

void render(const AnalysisReport& report, ReportFormat format, std::ostream& out) {
  switch (format) {
    case ReportFormat::text: render_text(report, out); break;
    case ReportFormat::json: render_json(report, out); break;
    case ReportFormat::html: render_html(report, out); break;
  }
}

}  // namespace

bool write_report(const AnalysisReport& report, ReportFormat format, const std::string& path, std::string* error) {
  if (path.empty() || path == "-") {
    render(report, format, std::cout);
    std::cout.flush();
    if (!std::cout) {
      if (error) *error = "standard output: write failed";
      return false;
    }
    return true;
  }
  // Write next to the target, then rename: a failed run never leaves a truncated report.
  const std::string partial = path + ".partial";
  {
    std::ofstream out(partial, std::ios::binary | std::ios::trunc);
    if (!out) {
      if (error) *error = partial + ": cannot create: " + std::strerror(errno);
      return false;
    }
    render(report, format, out);
    out.flush();
    if (!out) {
      if (error) *error = partial + ": write failed: " + std::strerror(errno);
      std::remove(partial.c_str());
      return false;
    }
  }
  if (std::rename(partial.c_str(), path.c_str()) != 0) {
    if (error) *error = path + ": cannot replace with the new report: " + std::strerror(errno);
    std::remove(partial.c_str());
    return false;
  }
  return true;
}

}  // namespace clastrace::analyze
