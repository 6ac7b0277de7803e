// SPDX-License-Identifier: Apache-2.0
#include "bug_programs_support.h"

#include <sstream>

namespace clastrace::bug_programs {

using namespace layer_launch;

namespace {

constexpr int kUnsupported = 77;  // bug_gpu.h: the driver lacks what the program needs

}  // namespace

uint64_t parse_address(const std::string& text) { return std::stoull(text, nullptr, 16); }

Range range_of(const json& pair) {
    return {parse_address(pair.at(0).get<std::string>()),
            parse_address(pair.at(1).get<std::string>())};
}

Range Replayed::range(const std::string& name) const {
    auto it = ranges.find(name);
    EXPECT_NE(it, ranges.end()) << "the program printed no range " << name;
    return it == ranges.end() ? Range{} : it->second;
}

std::string Replayed::describe() const {
    std::string text;
    for (const json& f : findings())
        text += f.at("rule").get<std::string>() + ": " + f.at("message").get<std::string>() + "\n";
    for (const json& h : hazards()) text += h.at("message").get<std::string>() + "\n";
    return text;
}

std::optional<Replayed> BugPrograms::capture_and_replay(const std::string& program,
                                                        const std::string& args) {
    const std::string trace = (dir / (program + ".clt")).string();
    ProcessResult app = run(quote(std::string(BUG_PROGRAM_DIR) + "/bug_" + program) + " " + args,
                            {{"CLASTRACE_OUTPUT", trace}});
    if (app.exitCode == kUnsupported) {
        unsupported_ = app.err;
        return std::nullopt;
    }
    EXPECT_EQ(app.exitCode, 0) << app.err;
    if (app.exitCode != 0) return std::nullopt;
    ProcessResult replay =
        run(quote(CLASTRACE_CLI) + " replay --json " + quote(trace), {}, /*withLayer=*/false);
    EXPECT_LE(replay.exitCode, 1) << replay.err;  // 1: findings
    Replayed r;
    try {
        r.report = json::parse(replay.out);
    } catch (const json::exception& e) {
        ADD_FAILURE() << "replay printed no JSON: " << e.what() << "\n" << replay.err;
        return std::nullopt;
    }
    EXPECT_TRUE(r.report.at("trace_damage").empty());
    EXPECT_TRUE(r.report.at("not_replayed").empty()) << r.report.at("not_replayed").dump();
    std::istringstream lines(app.out);
    std::string name, address;
    uint64_t size = 0;
    while (lines >> name >> address >> size) {
        const uint64_t begin = parse_address(address);
        r.ranges[name] = {begin, begin + size};
    }
    return r;
}

void expect_side(const json& side, const std::string& command, uint32_t submission,
                 uint32_t command_index, const std::string& field_prefix, bool write) {
    EXPECT_EQ(side.at("command"), command);
    EXPECT_EQ(side.at("submission"), submission);
    EXPECT_EQ(side.at("command_index"), command_index);
    EXPECT_EQ(side.at("field").get<std::string>().rfind(field_prefix, 0), 0u)
        << side.at("field") << " does not start with " << field_prefix;
    EXPECT_EQ(side.at("write"), write);
}

void expect_inside(Range inner, Range outer) {
    EXPECT_LT(inner.begin, inner.end);
    EXPECT_GE(inner.begin, outer.begin);
    EXPECT_LE(inner.end, outer.end);
}

void expect_equal(Range a, Range b) {
    EXPECT_EQ(a.begin, b.begin);
    EXPECT_EQ(a.end, b.end);
}

void expect_clean(const Replayed& r) {
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    EXPECT_TRUE(r.hazards().empty()) << r.describe();
    EXPECT_TRUE(r.report.at("clean").get<bool>());
}

void expect_bottom_level_reads_unordered(const Replayed& r, uint32_t clas_submission,
                                         uint32_t blas_submission, uint32_t blas_index,
                                         const std::string& fix_kind) {
    ASSERT_EQ(r.hazards().size(), 2u) << r.describe();
    const json& addresses = r.hazards().at(0);
    EXPECT_EQ(addresses.at("class"), "READ-AFTER-WRITE");
    expect_side(addresses.at("prior"), kClusterBuild, clas_submission, 0, "dstAddressesArray",
                true);
    expect_side(addresses.at("later"), kClusterBuild, blas_submission, blas_index,
                "srcInfosArray[0].clusterReferences", false);
    expect_equal(range_of(addresses.at("overlap")), r.range("clas_addresses"));
    EXPECT_EQ(addresses.at("fix").at("kind"), fix_kind);
    const json& objects = r.hazards().at(1);
    EXPECT_EQ(objects.at("class"), "READ-AFTER-WRITE");
    expect_side(objects.at("prior"), kClusterBuild, clas_submission, 0, "dstImplicitData", true);
    expect_side(objects.at("later"), kClusterBuild, blas_submission, blas_index,
                "srcInfosArray[0].clusterReferences[*]", false);
    expect_inside(range_of(objects.at("overlap")), r.range("clas_objects"));
}

}  // namespace clastrace::bug_programs
