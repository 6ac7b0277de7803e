// SPDX-License-Identifier: Apache-2.0
// The ray check (CLASTRACE_RAY_CHECK) against a KHR top level, for real on lavapipe 25:
// tests/apps/khr_build_app (an indexed-triangle BLAS and an AABB BLAS, a TLAS over one
// instance of each, with transforms and custom indices) captured with 10^5 rays; the app does
// not enable VK_KHR_ray_query, so the layer enables it. `clastrace replay --json` traces the
// same rays through the engine's rebuilt objects: every ray agrees. The same trace with one
// driver answer changed shows the disagreement, so a check that compares nothing cannot pass.
// Label rt-driver: skipped where lavapipe 25 is not unpacked.
#include "layer_launch_test.h"

#include <clastrace/testsupport/test_driver.h>
#include <clastrace/traces/records.h>
#include <clastrace/traces/trace_reader.h>
#include <clastrace/traces/trace_writer.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using namespace clastrace::layer_launch;
namespace fbs = clastrace::fbs;
namespace traces = clastrace::traces;

constexpr uint32_t kRays = 100000;
constexpr const char* kRayQueryLabel = "clastrace-ray-check/1 (ray query)";

// Copies the trace at `from` to `to`, record by record, with `edit` applied to each
// RayQueryCheck; a gtest failure on any error.
void copyTrace(const fs::path& from, const fs::path& to,
               const std::function<void(fbs::RayQueryCheckT&)>& edit) {
    traces::TraceError error;
    auto reader = traces::TraceReader::open(from.string(), &error);
    ASSERT_TRUE(reader) << error.message;
    ASSERT_TRUE(reader->header());
    std::unique_ptr<fbs::TraceHeaderT> header(reader->header()->UnPack());
    auto writer = traces::TraceWriter::create(to.string(), *header, {}, &error);
    ASSERT_TRUE(writer) << error.message;
    traces::RecordView view;
    while (reader->next(&view)) {
        if (const auto c = traces::contents_record(*view.record)) {  // deltas come decoded
            uint64_t hash = 0;
            ASSERT_FALSE(writer->add_contents(c->data(), c->size(), &hash));
        } else if (view.kind == fbs::RecordBody::RayQueryCheck) {
            fbs::RecordT record;
            view.record->UnPackTo(&record);
            edit(*record.body.AsRayQueryCheck());
            ASSERT_FALSE(writer->append(record));
        } else {
            ASSERT_FALSE(writer->append(view.record));
        }
    }
    ASSERT_FALSE(writer->finish());
}

class KhrRayCheck : public RayTracingLaunchTest {
protected:
    KhrRayCheck() : RayTracingLaunchTest("clastrace_khr_ray_check") {}

    void SetUp() override {
        RayTracingLaunchTest::SetUp();
        if (IsSkipped()) return;
        trace = dir / "khr.clt";
        captured = captureOnDriver(trace,
                                   std::string(CLASTRACE_KHR_APP) + " " +
                                       quote((dir / "out.json").string()),
                                   "--ray-check " + std::to_string(kRays) + " --log info");
        ASSERT_EQ(captured.exitCode, 0) << captured.out << captured.err;
    }

    // `clastrace replay --json` of `path`: its report, and its exit code in `exitCode`.
    json replay(const fs::path& path, int& exitCode) {
        ProcessResult r =
            run(std::string(CLASTRACE_CAPTURE_LAUNCHER) + " replay --json " + quote(path.string()),
                {}, false);
        exitCode = r.exitCode;
        return json::parse(r.out);
    }

    // The report's ray check with the ray-query label (there is one: one TLAS build).
    static json rayQueryCheck(const json& report) {
        json found;
        for (const json& c : report["ray_checks"])
            if (c["label"].get<std::string>().rfind(kRayQueryLabel, 0) == 0) {
                EXPECT_TRUE(found.is_null()) << "more than one ray-query check";
                found = c;
            }
        return found;
    }

    fs::path trace;
    ProcessResult captured;
};

TEST_F(KhrRayCheck, LayerEnablesRayQueryAndRecordsTheDriversAnswers) {
    // khr_build_app enables only VK_KHR_acceleration_structure: the layer adds VK_KHR_ray_query.
    EXPECT_NE(captured.err.find("the layer enables VK_KHR_ray_query"), std::string::npos)
        << captured.err;
    EXPECT_NE(captured.err.find("ray check of KHR top level"), std::string::npos) << captured.err;

    traces::TraceError error;
    auto reader = traces::TraceReader::open(trace.string(), &error);
    ASSERT_TRUE(reader) << error.message;
    size_t checks = 0, hits = 0, instance_hits[2] = {0, 0};
    traces::RecordView view;
    while (reader->next(&view)) {
        const auto* c = view.record->body_as_RayQueryCheck();
        if (!c) continue;
        ++checks;
        ASSERT_TRUE(c->rays() && c->results());
        EXPECT_EQ(c->rays()->size(), kRays);
        ASSERT_EQ(c->results()->size(), kRays);
        EXPECT_NE(c->device_handle(), 0u);  // the TLAS's device address
        for (const fbs::RayHitResult* h : *c->results()) {
            if (!h->hit()) continue;
            ++hits;
            ASSERT_LT(h->instance_id(), 2u);
            ++instance_hits[h->instance_id()];
            // The app's custom indices are 10 + instance; AABB hits have hit kind 0.
            EXPECT_EQ(h->instance_custom_index(), 10 + h->instance_id());
        }
    }
    EXPECT_EQ(checks, 1u);
    // Rays are aimed at the instances: both get hit, by many rays.
    EXPECT_GT(hits, kRays / 10);
    EXPECT_GT(instance_hits[0], kRays / 100);
    EXPECT_GT(instance_hits[1], kRays / 100);
}

TEST_F(KhrRayCheck, ReplayAgreesOnEveryRay) {
    int exitCode = -1;
    const json report = replay(trace, exitCode);
    const json check = rayQueryCheck(report);
    ASSERT_FALSE(check.is_null()) << report["ray_checks"].dump(1);
    EXPECT_TRUE(check["checked"].get<bool>()) << check["why_not"];
    EXPECT_GE(check["rays"].get<uint64_t>(), kRays);
    EXPECT_EQ(check["disagree"].get<uint64_t>(), 0u) << report["findings"].dump(1);
    EXPECT_GT(check["agree_hit"].get<uint64_t>(), kRays / 10);
    EXPECT_GT(check["agree_miss"].get<uint64_t>(), kRays / 10);
    // Ties and edge cases are counted apart; they stay rare.
    EXPECT_LT(check["tie"].get<uint64_t>() + check["edge"].get<uint64_t>(), kRays / 100);
    for (const json& f : report["findings"])
        EXPECT_NE(f["rule"], "CLASTRACE-replay-ray-check-disagrees") << f.dump();
}

TEST_F(KhrRayCheck, ReplayCatchesAChangedDriverAnswer) {
    const fs::path edited = dir / "edited.clt";
    uint32_t changed = 0;
    copyTrace(trace, edited, [&](fbs::RayQueryCheckT& c) {
        // The first hit becomes a miss, the first miss a hit on instance 0 at t = 1.
        bool hitDone = false, missDone = false;
        for (fbs::RayHitResult& r : c.results) {
            if (r.hit() && !hitDone) {
                r = fbs::RayHitResult(0, r.t(), r.instance_custom_index(), r.instance_id(),
                                      r.primitive_id(), r.geometry_index(), r.hit_kind(),
                                      r.barycentric_u(), r.barycentric_v());
                hitDone = true;
                ++changed;
            } else if (!r.hit() && !missDone) {
                r = fbs::RayHitResult(1, 1.0f, 10, 0, 0, 0, 0, 0.0f, 0.0f);
                missDone = true;
                ++changed;
            }
        }
    });
    ASSERT_EQ(changed, 2u);
    int exitCode = -1;
    const json report = replay(edited, exitCode);
    const json check = rayQueryCheck(report);
    ASSERT_FALSE(check.is_null()) << report["ray_checks"].dump(1);
    EXPECT_EQ(check["disagree"].get<uint64_t>(), 2u) << report["findings"].dump(1);
    EXPECT_EQ(exitCode, 1);  // findings
}

}  // namespace
