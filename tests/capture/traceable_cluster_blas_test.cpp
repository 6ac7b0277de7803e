// SPDX-License-Identifier: Apache-2.0
// Traceable cluster BLASes on lavapipe 25 (capture/README.md "Traceable cluster BLASes"):
// tests/apps/traceable_cluster_app builds served_scene.h's clusters and a cluster BLAS through the
// served extension, a KHR top level over it on its own device, and traces rays with a ray-query
// shader. With the mode on (the probe passes on lavapipe) the driver's rays hit each cluster at
// the height it lies at, with the cluster's reference index as the geometry index, and the
// served BLAS's bytes in the trace still replay byte for byte as the engine's. With the mode
// forced off, the driver cannot traverse the engine's layout: the same rays find nothing.
// Label rt-driver: skipped where lavapipe 25 is not unpacked.
#include "layer_launch_test.h"

#include <clastrace/testsupport/test_driver.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstdio>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using namespace clastrace::layer_launch;

constexpr uint32_t kClusters = 3, kRaysPerCluster = 6;
constexpr uint32_t kCheckRays = 16384;

struct DriverHit {
    uint32_t hit = 0, custom = 0, instance = 0, primitive = 0, geometry = 0;
    float t = 0;
};

// The app's "ray ..." lines, in order.
std::vector<DriverHit> parseHits(const std::string& out) {
    std::vector<DriverHit> hits;
    std::istringstream lines(out);
    std::string line;
    while (std::getline(lines, line)) {
        DriverHit h;
        unsigned index, kind;
        if (std::sscanf(line.c_str(),
                        "ray %u hit %u t %f custom %u instance %u primitive %u geometry %u kind %u",
                        &index, &h.hit, &h.t, &h.custom, &h.instance, &h.primitive, &h.geometry,
                        &kind) == 8)
            hits.push_back(h);
    }
    return hits;
}

class TraceableClusterBlas : public LayerLaunchTest {
protected:
    TraceableClusterBlas() : LayerLaunchTest("clastrace_traceable_cluster_blas") {}

    void SetUp() override {
        LayerLaunchTest::SetUp();
        if (IsSkipped()) return;
        driver = clastrace::testsupport::ray_tracing_driver();
        if (!driver) GTEST_SKIP() << clastrace::testsupport::kNoRayTracingDriver;
    }

    // The app captured with the mode `mode` (CLASTRACE_TRACEABLE_CLUSTERS) into `trace`.
    ProcessResult capture(const std::string& mode, const fs::path& trace,
                          const std::string& app_args = "") {
        return run("env CLASTRACE_TRACEABLE_CLUSTERS=" + mode + driver->environment_words() + " " +
                       CLASTRACE_CAPTURE_LAUNCHER + " capture --ray-check " +
                       std::to_string(kCheckRays) + " --log info -o " + quote(trace.string()) +
                       " --layer-path " + CLASTRACE_LAYER_MANIFEST_DIR + " -- " +
                       CLASTRACE_TRACEABLE_APP + " " + app_args,
                   {}, false);
    }

    // `trace` replays with its outputs compared byte for byte, no finding, `driver_bvh_ranges`
    // driver BVHs marked, and its one ray check (the app's top level) agreeing with the driver.
    void expect_exact_replay(const fs::path& trace, uint64_t driver_bvh_ranges) {
        const ProcessResult replayed =
            run(std::string(CLASTRACE_CAPTURE_LAUNCHER) + " replay --json " + quote(trace.string()),
                {}, false);
        const json report = json::parse(replayed.out);
        EXPECT_EQ(replayed.exitCode, 0) << replayed.out;
        EXPECT_TRUE(report["outputs_verified"].get<bool>());
        EXPECT_TRUE(report["findings"].empty()) << report["findings"].dump(1);
        EXPECT_EQ(report["counts"]["driver_bvh_ranges"].get<uint64_t>(), driver_bvh_ranges)
            << report["counts"];
        ASSERT_EQ(report["ray_checks"].size(), 1u) << report["ray_checks"].dump(1);
        const json& check = report["ray_checks"][0];
        EXPECT_TRUE(check["checked"].get<bool>()) << check;
        EXPECT_EQ(check["disagree"].get<uint64_t>(), 0u) << check;
        EXPECT_GE(check["agree_hit"].get<uint64_t>(), 100u) << check;
    }

    std::optional<clastrace::testsupport::TestDriver> driver;
};

// The driver's hits of traceable_cluster_app's rays: each cluster at the height it lies at.
void expect_hits_on_the_clusters(const ProcessResult& r) {
    const std::vector<DriverHit> hits = parseHits(r.out);
    ASSERT_EQ(hits.size(), kClusters * kRaysPerCluster + 1) << r.out;
    for (uint32_t c = 0; c < kClusters; ++c)
        for (uint32_t i = 0; i < kRaysPerCluster; ++i) {
            const DriverHit& h = hits[c * kRaysPerCluster + i];
            SCOPED_TRACE("cluster " + std::to_string(c) + " ray " + std::to_string(i));
            ASSERT_EQ(h.hit, 1u);
            EXPECT_FLOAT_EQ(h.t, 10.0f - float(c));  // cluster c lies at z = c, rays from z = 10
            EXPECT_EQ(h.geometry, c);                // = the cluster's reference index
            EXPECT_EQ(h.custom, 7u);
            EXPECT_EQ(h.instance, 0u);
            EXPECT_LT(h.primitive, 2 * (c + 1) * (c + 2));  // within the cluster's triangles
        }
    EXPECT_EQ(hits.back().hit, 0u);  // between the clusters
}

TEST_F(TraceableClusterBlas, DriverRaysHitTheServedClusters) {
    const ProcessResult r = capture("auto", dir / "on.clt");
    ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
    EXPECT_NE(r.err.find("traceable cluster BLASes: on"), std::string::npos) << r.err;
    expect_hits_on_the_clusters(r);
}

// A test parameter (the app's argument) as a test name: '-' is not allowed there.
std::string app_argument_name(const ::testing::TestParamInfo<const char*>& info) {
    std::string name = info.param;
    for (char& c : name)
        if (c == '-') c = '_';
    return name;
}

// A served MOVE_OBJECTS of the traceable BLAS moves the driver's BVH too (its old home is filled
// with 0xFF after the move): the driver's rays through a top level naming the new address hit as
// before, and the trace replays exactly, the move's destination marked as the driver's as well.
// The app's moves:
// - `move`: to an explicit destination;
// - `move-implicit`: to an implicit destination, under the default mode: the engine gives the
//   moved object the room of the driver's BVH it moves (recorded as implicit_object_room), and
//   the BVH is copied to the address the engine wrote to dstAddressesArray;
// - `move-indirect`: with every address indirected (srcInfosArray, srcInfosCount,
//   dstAddressesArray, dstSizesArray, scratchData read through cells): the layer takes the
//   destination from the engine's run and the source through the cells.
class MovedTraceableBlas : public TraceableClusterBlas,
                           public ::testing::WithParamInterface<const char*> {};

TEST_P(MovedTraceableBlas, IsHitAtItsNewAddressAndReplaysExactly) {
    const fs::path trace = dir / (std::string(GetParam()) + ".clt");
    const ProcessResult r = capture("auto", trace, GetParam());
    ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
    EXPECT_NE(r.out.find("moved to "), std::string::npos) << r.out;
    EXPECT_EQ(r.err.find("not moved"), std::string::npos) << r.err;
    expect_hits_on_the_clusters(r);
    expect_exact_replay(trace, 2);
}

INSTANTIATE_TEST_SUITE_P(Moves, MovedTraceableBlas,
                         ::testing::Values("move", "move-implicit", "move-indirect"),
                         app_argument_name);

// The app's two implicit BLAS addresses ("implicit blas at"), after checking that they lie a
// driver-sized room apart (the explicit answer: the driver's worst case) in a region (the served
// implicit-mode answer for two) that holds both rooms, and that no BLAS was left untraceable.
std::vector<unsigned long long> expect_implicit_rooms(const ProcessResult& r) {
    EXPECT_EQ(r.err.find("not traceable"), std::string::npos) << r.err;
    std::vector<unsigned long long> at;
    unsigned long long region = 0, explicit_size = 0;
    std::istringstream lines(r.out);
    for (std::string line; std::getline(lines, line);) {
        unsigned long long v = 0;
        if (std::sscanf(line.c_str(), "implicit blas at %llu", &v) == 1) at.push_back(v);
        std::sscanf(line.c_str(), "implicit region %llu", &region);
        std::sscanf(line.c_str(), "blas size %llu", &explicit_size);
    }
    EXPECT_EQ(at.size(), 2u) << r.out;
    if (at.size() != 2) return at;
    EXPECT_EQ(at[1] - at[0], explicit_size) << r.out;
    EXPECT_GE(region, 2 * explicit_size) << r.out;
    return at;
}

// Two traceable BLASes of one command at implicit destinations, under the default mode: the
// served implicit-mode size answer and the engine's packing give each object room for the
// driver's worst-case BLAS, so the second's driver BVH does not overrun the first, which the
// driver's rays hit (through the top level naming it). The trace records the room
// (implicit_object_room), so replay packs the objects the same way and the outputs
// (dstAddressesArray, dstSizesArray, the objects) compare byte for byte; both BLASes' driver BVHs
// are marked, and the ray check agrees. The same holds with every address indirected (the
// driver's BLASes go where the engine's run put the objects, not where the command's fields
// point) and without a dstAddressesArray (the layer knows each destination from the engine's run).
class ImplicitTraceableBlas : public TraceableClusterBlas,
                              public ::testing::WithParamInterface<const char*> {};

TEST_P(ImplicitTraceableBlas, GetsRoomForTheDriversBlasIsHitAndReplaysExactly) {
    const fs::path trace = dir / (std::string(GetParam()) + ".clt");
    const ProcessResult r = capture("auto", trace, GetParam());
    ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
    expect_implicit_rooms(r);
    expect_hits_on_the_clusters(r);
    expect_exact_replay(trace, 2);
}

INSTANTIATE_TEST_SUITE_P(Modes, ImplicitTraceableBlas,
                         ::testing::Values("implicit", "implicit-indirect", "implicit-unaddressed"),
                         app_argument_name);

// The served BLAS's bytes in the trace are the engine's (the driver's BVH lives only in the
// application's memory): replay rebuilds them and finds nothing at all, neither inside the
// object nor at the explicit dstSizesArray the build read, nor at the top level's scratch (sized
// by the driver's answer). The capture's ray check of the top level over the cluster BLAS
// records the driver's hits (geometry index translated to the cluster's), and replay's
// traversal of the replayed clusters agrees with every one.
TEST_F(TraceableClusterBlas, ServedBlasReplaysCleanAndItsRaysAgree) {
    const fs::path trace = dir / "on.clt";
    const ProcessResult r = capture("auto", trace);
    ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
    EXPECT_EQ(r.err.find("ray check of top level"), std::string::npos) << r.err;  // no skip
    const ProcessResult replayed =
        run(std::string(CLASTRACE_CAPTURE_LAUNCHER) + " replay --json " + quote(trace.string()), {},
            false);
    const json report = json::parse(replayed.out);
    EXPECT_TRUE(report["outputs_verified"].get<bool>());
    EXPECT_TRUE(report["findings"].empty()) << report["findings"].dump(1);
    EXPECT_EQ(replayed.exitCode, 0) << replayed.out;
    // The build's record marks the driver's BVH at the one BLAS (driver_bvh).
    EXPECT_EQ(report["counts"]["driver_bvh_ranges"].get<uint64_t>(), 1u) << report["counts"];
    size_t checked = 0;
    for (const json& check : report["ray_checks"]) {
        SCOPED_TRACE(check.dump());
        ASSERT_TRUE(check["checked"].get<bool>());
        EXPECT_EQ(check["rays"].get<uint64_t>(), kCheckRays);
        EXPECT_EQ(check["disagree"].get<uint64_t>(), 0u);
        EXPECT_GE(check["agree_hit"].get<uint64_t>(), 100u);  // rays aimed at the instance box
        ++checked;
    }
    EXPECT_EQ(checked, 1u) << report["ray_checks"].dump(1);
}

TEST_F(TraceableClusterBlas, WithTheModeOffTheDriverFindsNothing) {
    const ProcessResult r = capture("0", dir / "off.clt");
    ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
    EXPECT_EQ(r.err.find("traceable cluster BLASes: on"), std::string::npos) << r.err;
    const std::vector<DriverHit> hits = parseHits(r.out);
    ASSERT_EQ(hits.size(), kClusters * kRaysPerCluster + 1) << r.out;
    for (const DriverHit& h : hits) EXPECT_EQ(h.hit, 0u);
    // Nothing of the driver's in the trace: no driver_bvh.
    const ProcessResult replayed = run(std::string(CLASTRACE_CAPTURE_LAUNCHER) + " replay --json " +
                                           quote((dir / "off.clt").string()),
                                       {}, false);
    EXPECT_EQ(json::parse(replayed.out)["counts"]["driver_bvh_ranges"].get<uint64_t>(), 0u);
}

}  // namespace
