// SPDX-License-Identifier: Apache-2.0
// Events that break the input contract get an AnalysisInputError naming the rule and values.
#include <functional>

#include <gtest/gtest.h>

#include "clastrace/analyze/analyzer.h"

namespace clastrace::analyze {
namespace {

CommandInfo command(uint64_t ordinal, uint64_t submission = 0) {
    CommandInfo c;
    c.ordinal = ordinal;
    c.submission = submission;
    c.op_type = OpType::kBuildTriangleCluster;
    c.op_mode = OpMode::kImplicitDestinations;
    return c;
}

void expect_error(const std::function<void()>& f, const std::string& fragment) {
    try {
        f();
        ADD_FAILURE() << "no AnalysisInputError; expected one mentioning '" << fragment << "'";
    } catch (const AnalysisInputError& e) {
        EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
    }
}

TEST(AnalyzerInputErrors, EventsOutsideACommand) {
    Analyzer a;
    expect_error(
        [&] {
            a.on_region(RegionInfo{1, "r", 0, 16, RegionRole::kScratch, true});
        },
        "before any on_command");
    expect_error([&] { a.on_object(ObjectInfo{}); }, "before any on_command");
    expect_error([&] { a.on_hazard(HazardSummary{}); }, "before any on_command");
    expect_error([&] { a.on_build_sizes(BuildSizesInfo{}); }, "before any on_command");
}

TEST(AnalyzerInputErrors, OrdinalsMustIncrease) {
    Analyzer a;
    a.on_command(command(5));
    expect_error([&] { a.on_command(command(5)); }, "ordinal 5 follows ordinal 5");
    expect_error([&] { a.on_command(command(3)); }, "must strictly increase");
}

TEST(AnalyzerInputErrors, SubmissionsMustNotDecrease) {
    Analyzer a;
    a.on_command(command(0, 4));
    expect_error([&] { a.on_command(command(1, 3)); }, "submission 3 follows submission 4");
}

TEST(AnalyzerInputErrors, RegionPastTheEndOfTheAddressSpace) {
    Analyzer a;
    a.on_command(command(0));
    expect_error(
        [&] {
            a.on_region(RegionInfo{9, "big", UINT64_MAX - 15, 17, RegionRole::kScratch, true});
        },
        "region 9 'big' at 0xfffffffffffffff0 + 17 bytes passes the end");
    // The last byte, 2^64-1, cannot be covered: the end address must be representable.
    a.on_region(RegionInfo{10, "fits", UINT64_MAX - 15, 15, RegionRole::kScratch, true});
}

TEST(AnalyzerInputErrors, RegionIdReusedForAnotherRange) {
    Analyzer a;
    a.on_command(command(0));
    a.on_region(RegionInfo{3, "a", 0x1000, 64, RegionRole::kScratch, true});
    a.on_command(command(1));
    expect_error(
        [&] {
            a.on_region(RegionInfo{3, "a", 0x2000, 64, RegionRole::kScratch, true});
        },
        "region 3 reported as scratch 0x2000+64 but first seen at command 0 as scratch 0x1000+64");
}

TEST(AnalyzerInputErrors, UnknownEnumValues) {
    Analyzer a;
    CommandInfo c = command(0);
    c.op_type = static_cast<OpType>(42);
    expect_error([&] { a.on_command(c); }, "op_type 42");
    c.op_type = OpType::kOther;
    c.op_mode = static_cast<OpMode>(9);
    expect_error([&] { a.on_command(c); }, "op_mode 9");
    a.on_command(command(0));
    expect_error(
        [&] {
            a.on_region(RegionInfo{1, "", 0, 1, static_cast<RegionRole>(200), false});
        },
        "role 200");
    ObjectInfo o;
    o.type = static_cast<ObjectType>(77);
    expect_error([&] { a.on_object(o); }, "object type 77");
}

TEST(AnalyzerInputErrors, TruncateBitsAbove32) {
    Analyzer a;
    a.on_command(command(0));
    ObjectInfo o;
    o.op_index = 4;
    o.truncate_bits = 33;
    expect_error([&] { a.on_object(o); }, "command 0 op 4: positionTruncateBitCount 33 exceeds 32");
}

TEST(AnalyzerInputErrors, HazardMustNameTheOpenCommand) {
    Analyzer a;
    a.on_command(command(0));
    a.on_command(command(1));
    expect_error(
        [&] {
            a.on_hazard(HazardSummary{"RAW", 0, 7, 0, 0, ""});
        },
        "second command 7 while command 1 is open");
    expect_error(
        [&] {
            a.on_hazard(HazardSummary{"RAW", 2, 1, 0, 0, ""});
        },
        "first command 2 comes after");
    expect_error(
        [&] {
            a.on_hazard(HazardSummary{"RAW", 0, 1, UINT64_MAX, 2, ""});
        },
        "passes the end");
}

TEST(AnalyzerInputErrors, FinishTwiceAndEventsAfterFinish) {
    Analyzer a;
    a.on_command(command(0));
    (void)a.finish();
    expect_error([&] { (void)a.finish(); }, "finish() called twice");
    expect_error([&] { a.on_command(command(1)); }, "after finish");
}

}  // namespace
}  // namespace clastrace::analyze
