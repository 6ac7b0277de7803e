// SVG charts of an AnalysisReport, as inline <svg> elements with stable ids (tests find them):
// memory-map, hist-<op_type>, timeline.
#pragma once

#include <string>

#include "clastrace/analyze/report.h"

namespace clastrace::analyze {

inline constexpr std::size_t kMaxMapRegions = 3000;  // larger maps keep the largest regions
inline constexpr std::size_t kMaxOutlinedReuse = 150;  // more ordered-reuse pairs are not outlined

std::string svg_memory_map(const AnalysisReport& r);
std::string svg_size_histogram(const OpTypeSizes& sizes);
std::string svg_timeline(const AnalysisReport& r);
const char* role_color(RegionRole role);

}  // namespace clastrace::analyze
