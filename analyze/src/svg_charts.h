// SPDX-License-Identifier: Apache-2.0
// SVG charts of an AnalysisReport, as inline <svg> elements with stable ids (tests find them):
// memory-map, hist-<op_type>, timeline.
#pragma once

#include <string>

#include "clastrace/analyze/report.h"

namespace clastrace::analyze {

inline constexpr std::size_t kMaxMapRegions = 3000;    // larger maps keep the largest regions
inline constexpr std::size_t kMaxOutlinedReuse = 150;  // more ordered-reuse pairs are not outlined

std::string svg_memory_map(const AnalysisReport& r);
std::string svg_size_histogram(const OpTypeSizes& sizes);
std::string svg_timeline(const AnalysisReport& r);
// Per op type: actual object bytes vs the build-sizes worst case, implicit data used vs
// allocated, scratch required vs allocated, as "how full" bars (id size-budget).
std::string svg_size_budget(const AnalysisReport& r);
// Bytes per triangle by positionTruncateBitCount (id truncation-chart).
std::string svg_truncation(const AnalysisReport& r);
// GPU timestamp spans on the device clock: one bar per span from its start, as wide as its
// time (id gpu-timeline; rect.gpu-span with data-first, data-last, data-start-ns, data-ns).
std::string svg_gpu_spans(const AnalysisReport& r);
const char* role_color(RegionRole role);

}  // namespace clastrace::analyze
