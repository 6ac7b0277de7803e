// SPDX-License-Identifier: Apache-2.0
// The reachability closure on raw instance bytes: a top level reaches the bottom levels its
// last build's instances named (NV handles or KHR addresses, packed), a cluster bottom level
// the CLAS it names; inactive instances and shared bottom levels are read once or not at all.
#include "structure_reachability.h"

#include <clastrace/trace_building/consumer_records.h>

#include <gtest/gtest.h>

#include <map>

namespace clastrace::replay::detail {
namespace {

namespace tb = trace_building;

struct World {
    std::map<uint64_t, AddressRange> objects;             // handle -> bytes
    std::map<uint64_t, ClusterBottomLevel> cluster_blas;  // address -> what it names
    StructureReachability closure{[this](uint64_t h) -> std::optional<AddressRange> {
                                      auto it = objects.find(h);
                                      if (it == objects.end()) return std::nullopt;
                                      return it->second;
                                  },
                                  [this](uint64_t a) -> std::optional<ClusterBottomLevel> {
                                      auto it = cluster_blas.find(a);
                                      if (it == cluster_blas.end()) return std::nullopt;
                                      return it->second;
                                  }};
};

TEST(StructureReachability, PackedInstancesGiveTheReferenceAtByte56) {
    const std::vector<uint8_t> bytes = tb::packed_instances({0x1111, 0, 0xABCDEF0123});
    EXPECT_EQ(bytes.size(), 3 * kInstanceBytes);
    EXPECT_EQ(packed_instance_references(bytes, 3),
              (std::vector<uint64_t>{0x1111, 0, 0xABCDEF0123}));
    // Instances past the end of the bytes are left out.
    EXPECT_EQ(packed_instance_references(bytes, 5).size(), 3u);
    EXPECT_EQ(packed_instance_references({bytes.data(), 100}, 3).size(), 1u);
}

TEST(StructureReachability, KhrTopLevelReachesBottomLevelsAndClustersByAddress) {
    World w;
    // A KHR bottom level at address 0x9000 (handle 0xB1), a cluster bottom level at 0x20000
    // naming two CLAS, and the top level 0x77 over both, with an inactive instance between.
    w.objects[0xB1] = {0x9000, 0x9400};
    w.objects[0x77] = {0x8000, 0x8800};
    w.closure.on_created(0xB1, 0x9000);
    w.closure.on_created(0x77, 0x8000);
    w.cluster_blas[0x20000] = {{0x20000, 0x20100},
                               {{0, {0x30000, 0x30200}}, {5, {0x30200, 0x30380}}}};
    const std::vector<uint8_t> instances = tb::packed_instances({0x9000, 0, 0x20000, 0x9000});
    w.closure.on_top_level_built(0x77, packed_instance_references(instances, 4));

    const std::vector<ReachedStructure> reached = w.closure.reach(0, 0x8000, "as");
    ASSERT_EQ(reached.size(), 5u);
    EXPECT_EQ(reached[0].range, (AddressRange{0x8000, 0x8800}));
    EXPECT_EQ(reached[0].path, "as: top level 0x77");
    EXPECT_EQ(reached[1].handle, 0xB1u);  // instances 0 and 3 name it: read once
    EXPECT_EQ(reached[1].path, "as: top level 0x77 > instance 0: bottom level 0xb1");
    EXPECT_EQ(reached[2].range, (AddressRange{0x20000, 0x20100}));
    EXPECT_EQ(reached[2].path, "as: top level 0x77 > instance 2: cluster bottom level 0x20000");
    EXPECT_EQ(reached[4].range, (AddressRange{0x30200, 0x30380}));
    EXPECT_EQ(reached[4].path,
              "as: top level 0x77 > instance 2: cluster bottom level 0x20000 > cluster 5: CLAS "
              "0x30200");
    EXPECT_EQ(w.closure.top_levels_naming(0xB1), (std::vector<uint64_t>{0x77}));

    // The instance buffer's later contents do not matter: only a new build changes the closure.
    w.closure.on_top_level_built(0x77,
                                 packed_instance_references(tb::packed_instances({0x9000}), 1));
    EXPECT_EQ(w.closure.reach(0x77, 0, "as").size(), 2u);
    // A destroyed bottom level is no longer reached by its address.
    w.closure.on_destroyed(0xB1);
    EXPECT_EQ(w.closure.reach(0x77, 0, "as").size(), 1u);
}

TEST(StructureReachability, UnboundOrUnknownStructuresReachNothing) {
    World w;
    w.closure.on_created(0x77, 0x8000);  // created, never bound
    w.closure.on_top_level_built(0x77, {0xDEAD});
    EXPECT_TRUE(w.closure.reach(0x77, 0, "as").empty());
    EXPECT_TRUE(w.closure.reach(0, 0x4444, "as").empty());
}

}  // namespace
}  // namespace clastrace::replay::detail
