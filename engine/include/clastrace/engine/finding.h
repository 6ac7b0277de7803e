// SPDX-License-Identifier: Apache-2.0
// A rule an input broke: named by its VUID string verbatim (as the validation layers
// print it) or by "CLASTRACE-<rule>" for rules of the engine itself.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace clastrace::engine {

struct Finding {
    std::string rule;     // "VUID-..." or "CLASTRACE-..."
    std::string message;  // names the address, the field and the op index
    int64_t op_index = -1;
    uint64_t address = 0;  // the address the rule is about, 0 when none
};

// Engine rules (not in the spec's valid usage, but a driver would misbehave):
inline constexpr const char* kRuleIndexOutOfRange =
    "CLASTRACE-index-out-of-range";                                        // index >= vertexCount
inline constexpr const char* kRuleMemoryFault = "CLASTRACE-memory-fault";  // address outside memory
inline constexpr const char* kRuleInstanceOutsideLimit =
    "CLASTRACE-instantiation-outside-bounding-box-limit";
inline constexpr const char* kRuleNotATemplate =
    "CLASTRACE-not-a-cluster-template";  // bad object at address
inline constexpr const char* kRuleUnsupportedFormat = "CLASTRACE-unsupported-vertex-format";
inline constexpr const char* kRuleCountAboveInput = "CLASTRACE-count-above-triangle-cluster-input";
inline constexpr const char* kRuleUniqueGeometryCount =
    "CLASTRACE-unique-geometry-count-above-input";
inline constexpr const char* kRuleGeometryIndexAboveInput = "CLASTRACE-geometry-index-above-input";
inline constexpr const char* kRuleBeyondEngineFormat =
    "CLASTRACE-count-beyond-engine-format";  // > 256 vertices/triangles

bool has_rule(const std::vector<Finding>& findings, const std::string& rule);

}  // namespace clastrace::engine
