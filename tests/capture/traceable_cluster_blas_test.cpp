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
    ProcessResult capture(const std::string& mode, const fs::path& trace) {
        return run("env CLASTRACE_TRACEABLE_CLUSTERS=" + mode + driver->environment_words() + " " +
                       CLASTRACE_CAPTURE_LAUNCHER + " capture --ray-check " +
                       std::to_string(kCheckRays) + " --log info -o " + quote(trace.string()) +
                       " --layer-path " + CLASTRACE_LAYER_MANIFEST_DIR + " -- " +
                       CLASTRACE_TRACEABLE_APP,
                   {}, false);
    }

    std::optional<clastrace::testsupport::TestDriver> driver;
};

TEST_F(TraceableClusterBlas, DriverRaysHitTheServedClusters) {
    const ProcessResult r = capture("auto", dir / "on.clt");
    ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
    EXPECT_NE(r.err.find("traceable cluster BLASes: on"), std::string::npos) << r.err;
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
