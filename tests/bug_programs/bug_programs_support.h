// SPDX-License-Identifier: Apache-2.0
// Each program of this folder, written apart from the project's own test apps, carries one
// deliberate bug that is silent at run time. Captured through the layer on the test driver and
// replayed with `clastrace replay --json`, each must give exactly its finding: the hazard class
// or rule, both commands, and the range the program says the bug touches; the variants without
// the bug must replay clean. The tests live in one file a theme (bug_*_test.cpp); this is what
// they share: the fixture, the report it gives back, the checks more than one theme uses.
#pragma once

#include "layer_launch_test.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstdint>
#include <map>
#include <optional>
#include <string>

namespace clastrace::bug_programs {

using nlohmann::json;

inline constexpr const char* kClusterBuild = "vkCmdBuildClusterAccelerationStructureIndirectNV";

struct Range {
    uint64_t begin = 0, end = 0;
};

uint64_t parse_address(const std::string& text);
// A JSON pair of hex addresses, as the report writes a range.
Range range_of(const json& pair);

// What one run said: the replay's JSON report and the ranges the program printed.
struct Replayed {
    json report;
    std::map<std::string, Range> ranges;

    const json& hazards() const { return report.at("hazards").at("hazards"); }
    const json& findings() const { return report.at("findings"); }
    Range range(const std::string& name) const;
    std::string describe() const;
};

class BugPrograms : public layer_launch::LayerLaunchTest {
public:
    BugPrograms() : LayerLaunchTest("clastrace_bug_programs") {}

protected:
    // `program ARGS` under the capture layer, then the replay of its trace; nullopt when the
    // program cannot run here (the caller skips) or a step failed (already reported).
    std::optional<Replayed> capture_and_replay(const std::string& program,
                                               const std::string& args = "");

    std::string unsupported_;
};

#define CAPTURE_AND_REPLAY(var, ...)                                       \
    std::optional<Replayed> var##_run = capture_and_replay(__VA_ARGS__);   \
    if (!var##_run && !unsupported_.empty()) GTEST_SKIP() << unsupported_; \
    ASSERT_TRUE(var##_run);                                                \
    const Replayed& var = *var##_run

// One side of a hazard: its command, where it ran (the submission and the command's index in
// its command buffer as the program recorded it), and the field its access came from.
void expect_side(const json& side, const std::string& command, uint32_t submission,
                 uint32_t command_index, const std::string& field_prefix, bool write);
void expect_inside(Range inner, Range outer);
void expect_equal(Range a, Range b);
void expect_clean(const Replayed& r);
// The bottom level's two reads of what the cluster build wrote, with nothing ordering them:
// the CLAS addresses (its clusterReferences, the cluster build's dstAddressesArray) and the
// CLAS objects.
void expect_bottom_level_reads_unordered(const Replayed& r, uint32_t clas_submission,
                                         uint32_t blas_submission, uint32_t blas_index,
                                         const std::string& fix_kind);

}  // namespace clastrace::bug_programs
