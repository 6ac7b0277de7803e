// SPDX-License-Identifier: Apache-2.0
// Deterministic random event streams with hostile values (huge addresses and counts, bad
// enums, control characters and invalid UTF-8 in labels, events out of order): every event is
// either accepted or refused with AnalysisInputError, and every report renders.
#include <random>
#include <sstream>

#include <gtest/gtest.h>

#include "clastrace/analyze/analyzer.h"
#include "clastrace/analyze/render.h"

namespace clastrace::analyze {
namespace {

uint64_t hostile_u64(std::mt19937_64& rng) {
    switch (rng() % 6) {
    case 0: return 0;
    case 1: return UINT64_MAX - rng() % 64;
    case 2: return rng();
    case 3: return rng() % 4096;
    case 4: return uint64_t{1} << (rng() % 64);
    default: return 0x10000 + (rng() % 64) * 256;
    }
}

std::string hostile_label(std::mt19937_64& rng) {
    static const char* labels[] = {"",
                                   "scratch",
                                   "<script>alert(1)</script>",
                                   "line\nbreak\ttab",
                                   "\xff\xfe bad utf8",
                                   "&amp; \"quoted\" 'single'"};
    std::string s = labels[rng() % 6];
    if (rng() % 8 == 0) s += std::string(300, 'x');
    return s;
}

TEST(AnalyzerMutation, RandomHostileStreamsNeverCrashAndAlwaysRender) {
    std::mt19937_64 rng(20261122);
    int refused = 0, accepted = 0;
    for (int round = 0; round < 60; ++round) {
        AnalyzerLimits limits;
        limits.max_listed_commands = 1 + rng() % 32;
        limits.timeline_buckets = 1 + rng() % 16;
        limits.max_tracked_regions = 1 + rng() % 64;
        limits.max_listed_overlaps = rng() % 16;
        limits.max_listed_hazards = rng() % 8;
        limits.recent_command_rows = rng() % 8;
        limits.top_commands = rng() % 4;
        Analyzer a(hostile_label(rng), limits);
        uint64_t ordinal = 0;
        for (int e = 0; e < 400; ++e) {
            try {
                switch (rng() % 7) {
                case 0: {
                    CommandInfo c;
                    c.ordinal = rng() % 10 == 0 ? hostile_u64(rng) : ++ordinal;
                    c.submission = ordinal / 3;
                    c.name = hostile_label(rng);
                    c.op_type = static_cast<OpType>(rng() % 8);
                    c.op_mode = static_cast<OpMode>(rng() % 5);
                    c.op_count = hostile_u64(rng);
                    c.triangles = hostile_u64(rng);
                    if (rng() % 2) c.gpu_ns = hostile_u64(rng);
                    if (rng() % 2) c.replay_ns = hostile_u64(rng);
                    a.on_command(c);
                    ordinal = c.ordinal;
                    break;
                }
                case 1:
                case 2:
                    a.on_region(RegionInfo{rng() % 40, hostile_label(rng), hostile_u64(rng),
                                           hostile_u64(rng), static_cast<RegionRole>(rng() % 15),
                                           rng() % 2 == 0});
                    break;
                case 3: {
                    ObjectInfo o;
                    o.type = static_cast<ObjectType>(rng() % 5);
                    o.engine_bytes = hostile_u64(rng);
                    if (rng() % 2) o.driver_bytes = hostile_u64(rng);
                    if (rng() % 2) o.engine_bytes_untruncated = hostile_u64(rng);
                    o.triangles = hostile_u64(rng);
                    o.truncate_bits = static_cast<uint32_t>(rng() % 40);
                    a.on_object(o);
                    break;
                }
                case 4:
                    a.on_build_sizes(BuildSizesInfo{hostile_u64(rng), 0, 0, 0, 0, 0,
                                                    hostile_u64(rng), hostile_u64(rng), 0});
                    break;
                case 5:
                    a.on_hazard(
                        HazardSummary{hostile_label(rng), (ordinal >= 3 ? ordinal - rng() % 3 : 0),
                                      rng() % 3 ? ordinal : hostile_u64(rng), hostile_u64(rng),
                                      hostile_u64(rng), hostile_label(rng)});
                    break;
                default:
                    a.on_trace_bytes(
                        TraceBytes{hostile_u64(rng), hostile_u64(rng), hostile_u64(rng)});
                }
                ++accepted;
            } catch (const AnalysisInputError& e) {
                ++refused;
                EXPECT_GT(std::string(e.what()).size(), 10u);
            }
        }
        AnalysisReport r = a.finish();
        EXPECT_LE(r.overlaps.size(), limits.max_listed_overlaps + limits.max_listed_hazards);
        EXPECT_LE(r.hazards.size(), limits.max_listed_hazards);
        EXPECT_LE(r.timeline.size(), limits.timeline_buckets);
        EXPECT_LE(r.regions, limits.max_tracked_regions);
        const std::string text = render_text(r);
        std::istringstream lines(text);
        for (std::string line; std::getline(lines, line);)
            ASSERT_LE(line.size(), kTextColumns) << line;
        const std::string html = render_html(r);
        EXPECT_EQ(html.find("<script"), std::string::npos);
        EXPECT_FALSE(render_json(r).empty());
    }
    EXPECT_GT(accepted, 1000);
    EXPECT_GT(refused, 100);
}

}  // namespace
}  // namespace clastrace::analyze
