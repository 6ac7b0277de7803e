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
#include <clastrace/testsupport/trace_records.h>
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

class KhrTwoDevices : public RayTracingLaunchTest {
protected:
    KhrTwoDevices() : RayTracingLaunchTest("clastrace_khr_two_devices") {}

    void SetUp() override {
        RayTracingLaunchTest::SetUp();
        if (IsSkipped()) return;
        trace = dir / "two_devices.clt";
        ProcessResult r = captureOnDriver(trace, std::string(CLASTRACE_TWO_DEVICES_APP) + " " +
                                                     quote((dir / "out.json").string()));
        ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
        rounds = json::parse(readText(dir / "out.json"))["rounds"];
        read();
    }

    void read() {
        clastrace::traces::TraceError error;
        auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
        ASSERT_TRUE(reader) << error.message;
        clastrace::traces::RecordView view;
        using clastrace::testsupport::unpack_record;
        while (reader->next(&view)) {
            unpack_record<fbs::AccelerationStructureCreate>(view, captured.creates);
            unpack_record<fbs::CmdBuildAccelerationStructuresKHR>(view, captured.builds);
            unpack_record<fbs::CmdWriteAccelerationStructuresProperties>(view, captured.properties);
            unpack_record<fbs::QueryPoolResults>(view, captured.results);
        }
        EXPECT_TRUE(reader->damage().empty()) << reader->damage().front().message;
    }

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
