// SPDX-License-Identifier: Apache-2.0
// The layer's per-device tables across devices in turn: tests/apps/khr_two_devices_app creates a
// device, builds a KHR BLAS, reads its compacted size and destroys the device with the BLAS and
// the query pool alive, then does the same on a second device (which first reads a timestamp
// pool). Each device's records name only its own structures and pools: the second device's
// timestamp read is no structure-property read even where the driver hands it the first
// device's freed pool handle, and `clastrace replay` of the trace is clean.
// Label rt-driver: skipped where lavapipe 25 is not unpacked.
#include "layer_launch_test.h"

#include <clastrace/testsupport/test_driver.h>
#include <clastrace/traces/trace_reader.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using namespace clastrace::layer_launch;
namespace fbs = clastrace::fbs;

struct CapturedTrace {
    std::vector<fbs::AccelerationStructureCreateT> creates;
    std::vector<fbs::CmdBuildAccelerationStructuresKHRT> builds;
    std::vector<fbs::CmdWriteAccelerationStructuresPropertiesT> properties;
    std::vector<fbs::QueryPoolResultsT> results;
};

class KhrTwoDevices : public LayerLaunchTest {
protected:
    KhrTwoDevices() : LayerLaunchTest("clastrace_khr_two_devices") {}

    void SetUp() override {
        LayerLaunchTest::SetUp();
        if (IsSkipped()) return;
        driver = clastrace::testsupport::ray_tracing_driver();
        if (!driver) GTEST_SKIP() << clastrace::testsupport::kNoRayTracingDriver;
        trace = dir / "two_devices.clt";
        ProcessResult r =
            run("env" + driver->environment_words() + " " + CLASTRACE_CAPTURE_LAUNCHER +
                    " capture -o " + quote(trace.string()) + " --layer-path " +
                    CLASTRACE_LAYER_MANIFEST_DIR + " -- " + CLASTRACE_TWO_DEVICES_APP + " " +
                    quote((dir / "out.json").string()),
                {}, false);
        ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
        rounds = json::parse(readText(dir / "out.json"))["rounds"];
        read();
    }

    void read() {
        clastrace::traces::TraceError error;
        auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
        ASSERT_TRUE(reader) << error.message;
        clastrace::traces::RecordView view;
        while (reader->next(&view)) {
            const fbs::Record& r = *view.record;
            switch (view.kind) {
            case fbs::RecordBody::AccelerationStructureCreate:
                captured.creates.emplace_back();
                r.body_as_AccelerationStructureCreate()->UnPackTo(&captured.creates.back());
                break;
            case fbs::RecordBody::CmdBuildAccelerationStructuresKHR:
                captured.builds.emplace_back();
                r.body_as_CmdBuildAccelerationStructuresKHR()->UnPackTo(&captured.builds.back());
                break;
            case fbs::RecordBody::CmdWriteAccelerationStructuresProperties:
                captured.properties.emplace_back();
                r.body_as_CmdWriteAccelerationStructuresProperties()->UnPackTo(
                    &captured.properties.back());
                break;
            case fbs::RecordBody::QueryPoolResults:
                captured.results.emplace_back();
                r.body_as_QueryPoolResults()->UnPackTo(&captured.results.back());
                break;
            default: break;
            }
        }
        EXPECT_TRUE(reader->damage().empty()) << reader->damage().front().message;
    }

    std::optional<clastrace::testsupport::TestDriver> driver;
    fs::path trace;
    json rounds;
    CapturedTrace captured;
};

TEST_F(KhrTwoDevices, EachDevicesRecordsNameItsOwnStructuresAndPools) {
    ASSERT_EQ(rounds.size(), 2u);
    ASSERT_EQ(captured.creates.size(), 2u);
    ASSERT_EQ(captured.builds.size(), 2u);
    ASSERT_EQ(captured.properties.size(), 2u);
    // The timestamp pools of the second device are read too, but only property reads are
    // records: also the one made after its property pool was destroyed, which lavapipe gives the
    // destroyed pool's handle (DestroyQueryPool drops the mark).
    ASSERT_EQ(captured.results.size(), 2u) << "second timestamp pool " << rounds[1]["timestampPool"]
                                           << ", first property pool " << rounds[0]["propertyPool"];
    EXPECT_TRUE(rounds[1]["handleReused"].get<bool>())
        << "the driver did not reuse the destroyed pool's handle: this check is weaker there";
    for (size_t i = 0; i < 2; ++i) {
        SCOPED_TRACE(i);
        const json& round = rounds[i];
        EXPECT_EQ(captured.creates[i].acceleration_structure, round["blas"].get<uint64_t>());
        EXPECT_EQ(captured.creates[i].buffer, round["storage"].get<uint64_t>());
        EXPECT_EQ(captured.creates[i].device_address, round["address"].get<uint64_t>());
        ASSERT_EQ(captured.builds[i].infos.size(), 1u);
        EXPECT_EQ(captured.builds[i].infos[0]->dst, round["blas"].get<uint64_t>());
        EXPECT_EQ(captured.builds[i].infos[0]->src, 0u);
        EXPECT_EQ(captured.properties[i].query_pool, round["propertyPool"].get<uint64_t>());
        EXPECT_EQ(captured.properties[i].acceleration_structures,
                  std::vector<uint64_t>{round["blas"].get<uint64_t>()});
        EXPECT_EQ(captured.results[i].query_pool, round["propertyPool"].get<uint64_t>());
        ASSERT_EQ(captured.results[i].values.size(), 1u);
        EXPECT_EQ(captured.results[i].values[0], round["compactedSize"].get<uint64_t>());
    }

    ProcessResult replayed =
        run(std::string(CLASTRACE_CAPTURE_LAUNCHER) + " replay --json " + quote(trace.string()), {},
            false);
    EXPECT_EQ(replayed.exitCode, 0) << replayed.out << replayed.err;
    const json report = json::parse(replayed.out);
    EXPECT_TRUE(report["clean"].get<bool>()) << replayed.out;
    EXPECT_TRUE(report["hazards"]["hazards"].empty()) << report["hazards"].dump(1);
    EXPECT_TRUE(report["findings"].empty()) << report["findings"].dump(1);
}

}  // namespace
