// SPDX-License-Identifier: Apache-2.0
// Renderers of an AnalysisReport. Text: aligned tables no wider than 100 columns.
// JSON: stable field names, documented in docs/analyze.md, with schema_version.
// HTML: one self-contained file, inline CSS and SVG, no script and no network reference.
#pragma once

#include <ostream>
#include <string>

#include "clastrace/analyze/report.h"

namespace clastrace::analyze {

inline constexpr std::size_t kTextColumns = 100;

void render_text(const AnalysisReport& report, std::ostream& out);
void render_json(const AnalysisReport& report, std::ostream& out);
void render_html(const AnalysisReport& report, std::ostream& out);

std::string render_text(const AnalysisReport& report);
std::string render_json(const AnalysisReport& report);
std::string render_html(const AnalysisReport& report);

}  // namespace clastrace::analyze
