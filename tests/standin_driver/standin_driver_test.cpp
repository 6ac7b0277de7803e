// SPDX-License-Identifier: MIT
// The stand-in driver on lavapipe, without the capture layer: the extension is listed, its
// sizes are its own, and one triangle-cluster build and one bottom-level build land where its
// layout says (inside the implicit region, not at its first byte, padded sizes written).
#include "cluster_test_device.h"
#include "served_scene.h"
#include "standin_layout.h"

#include <clastrace/engine/build_sizes.h>
#include <clastrace/engine/properties.h>

#include <gtest/gtest.h>

#include <dlfcn.h>

#include <cstdint>
#include <cstdlib>
#include <cstring>

namespace {

using clastrace::testapp::Buffer;
using clastrace::testapp::ClusterTestDevice;

class StandinDriver : public ::testing::Test {
protected:
    void SetUp() override {
        setenv("VK_ADD_LAYER_PATH", CLASTRACE_STANDIN_MANIFEST_DIR, 1);
        setenv("VK_INSTANCE_LAYERS", "VK_LAYER_CLASTRACE_standin_driver", 1);
        gpu.createInstance("standin_driver_test");
    }
    void TearDown() override {
        if (gpu.device) gpu.destroy();
    }
    ClusterTestDevice gpu;
};

VkAccelerationStructureBuildSizesInfoKHR sizes_of(
    ClusterTestDevice& gpu, const VkClusterAccelerationStructureInputInfoNV& input) {
    VkAccelerationStructureBuildSizesInfoKHR sizes{};
    sizes.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR;
    gpu.getBuildSizes(gpu.device, &input, &sizes);
    return sizes;
}

template <class T>
Buffer upload(ClusterTestDevice& gpu, const T* data, size_t bytes) {
    Buffer b = gpu.makeBuffer(bytes, 0);
    std::memcpy(b.mapped, data, bytes);
    return b;
}

TEST_F(StandinDriver, ListsTheExtensionTheDriverBelowLacks) {
    EXPECT_TRUE(gpu.hasClusterExtension());
}

TEST_F(StandinDriver, AnswersItsOwnSizesLargerThanTheEngines) {
    gpu.createDevice();
    served_scene::Commands c;
    served_scene::makeCommands({}, c);
    for (const VkClusterAccelerationStructureInputInfoNV* input :
         {&c.clusters.input, &c.blas.input}) {
        const auto standin = sizes_of(gpu, *input);
        const auto engine = clastrace::engine::cluster_build_sizes(
            *input, clastrace::engine::EngineProperties::nvidia_default());
        EXPECT_GT(standin.buildScratchSize, engine.build_scratch_size);
        EXPECT_GT(standin.accelerationStructureSize, engine.acceleration_structure_size);
        EXPECT_EQ(standin.buildScratchSize,
                  clastrace::standin::standin_build_sizes(*input).build_scratch_size);
    }
}

// The pause events the stand-in holds (its test hook, found in the library the loader loaded).
size_t live_pause_events() {
    void* layer = dlopen(CLASTRACE_STANDIN_LIBRARY, RTLD_NOW | RTLD_NOLOAD);
    EXPECT_NE(layer, nullptr) << "the stand-in layer is not loaded";
    if (!layer) return SIZE_MAX;
    auto count =
        reinterpret_cast<size_t (*)()>(dlsym(layer, "clastrace_standin_live_pause_events"));
    EXPECT_NE(count, nullptr);
    const size_t events = count ? count() : SIZE_MAX;
    dlclose(layer);
    return events;
}

// The clusters' destinations given through indirection cells: the stand-in must still place
// and report at its own layout.
void indirect_destinations(const Buffer& cells,
                           VkClusterAccelerationStructureCommandsInfoNV& info) {
    auto* cell = reinterpret_cast<uint64_t*>(cells.mapped);
    cell[0] = info.dstImplicitData, cell[1] = info.scratchData;
    cell[2] = info.dstAddressesArray.deviceAddress, cell[3] = info.dstSizesArray.deviceAddress;
    info.dstImplicitData = cells.address, info.scratchData = cells.address + 8;
    info.dstAddressesArray.deviceAddress = cells.address + 16;
    info.dstSizesArray.deviceAddress = cells.address + 24;
    info.addressResolutionFlags =
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_IMPLICIT_DATA_BIT_NV |
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SCRATCH_DATA_BIT_NV |
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV |
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_SIZES_ARRAY_BIT_NV;
}

// Builds the served scene's clusters and bottom level (the clusters' destinations through
// indirection cells when `indirected`), checks the stand-in's layout, then frees the command
// buffer and checks that its pause events went with it.
void build_at_own_layout(ClusterTestDevice& gpu, bool indirected) {
    gpu.createDevice();
    served_scene::Commands c;
    served_scene::makeCommands({}, c);
    const auto cluster_sizes = sizes_of(gpu, c.clusters.input);
    const auto blas_sizes = sizes_of(gpu, c.blas.input);

    served_scene::Addresses a;
    Buffer outputs = gpu.makeBuffer(4096, 0, 0xEE);
    a.dstAddresses = outputs.address;
    a.dstSizes = outputs.address + 256;
    a.blasDstAddresses = outputs.address + 512;
    a.blasDstSizes = outputs.address + 768;
    Buffer implicit = gpu.makeBuffer(cluster_sizes.accelerationStructureSize, 0);
    Buffer scratch = gpu.makeBuffer(cluster_sizes.buildScratchSize, 0);
    Buffer blas_implicit = gpu.makeBuffer(blas_sizes.accelerationStructureSize, 0);
    Buffer blas_scratch = gpu.makeBuffer(blas_sizes.buildScratchSize, 0);
    a.implicitData = implicit.address;
    a.scratch = scratch.address;
    a.blasImplicit = blas_implicit.address;
    a.blasScratch = blas_scratch.address;
    // The inputs refer to their own addresses: two passes, the second with the real ones.
    served_scene::Inputs in = served_scene::makeInputs(a);
    Buffer vertices = upload(gpu, in.vertices.data(), in.vertices.size() * 4);
    Buffer indices = upload(gpu, in.indices.data(), in.indices.size() * 4);
    a.vertices = vertices.address;
    a.indices = indices.address;
    in = served_scene::makeInputs(a);
    Buffer infos = upload(gpu, in.infos.data(), in.infos.size() * sizeof(in.infos[0]));
    Buffer blas_infos = upload(gpu, &in.blasInfo, sizeof in.blasInfo);
    Buffer counts = upload(gpu, in.counts, sizeof in.counts);
    a.infos = infos.address;
    a.blasInfos = blas_infos.address;
    a.counts = counts.address;
    served_scene::makeCommands(a, c);
    Buffer cells = gpu.makeBuffer(32, 0);
    if (indirected) indirect_destinations(cells, c.clusters);

    VkCommandBuffer cb = gpu.beginCommands();
    gpu.cmdBuildClusters(cb, &c.clusters);
    VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, VK_ACCESS_MEMORY_WRITE_BIT,
                            VK_ACCESS_MEMORY_READ_BIT};
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT,
                         0, 1, &barrier, 0, nullptr, 0, nullptr);
    gpu.cmdBuildClusters(cb, &c.blas);
    gpu.submitAndWait(cb);

    const auto* addresses = reinterpret_cast<const uint64_t*>(outputs.mapped);
    const auto* sizes = reinterpret_cast<const uint32_t*>(outputs.mapped + 256);
    const auto properties = clastrace::engine::EngineProperties::nvidia_default();
    uint64_t previous_end = implicit.address;
    for (uint32_t i = 0; i < served_scene::kClusterCount; ++i) {
        SCOPED_TRACE(i);
        EXPECT_GE(addresses[i], implicit.address + clastrace::standin::kImplicitLeadingBytes);
        EXPECT_GE(addresses[i], previous_end);
        EXPECT_EQ(addresses[i] % properties.cluster_byte_alignment, 0u);
        EXPECT_GT(sizes[i], clastrace::standin::kObjectPaddingBytes);
        EXPECT_EQ(sizes[i] % properties.cluster_byte_alignment, 0u);
        EXPECT_LE(addresses[i] + sizes[i], implicit.address + implicit.size);
        previous_end = addresses[i] + sizes[i];
    }
    EXPECT_GT(addresses[0], implicit.address);  // not packed from the region's first byte
    const auto* blas_address = reinterpret_cast<const uint64_t*>(outputs.mapped + 512);
    const auto* blas_size = reinterpret_cast<const uint32_t*>(outputs.mapped + 768);
    EXPECT_EQ(*blas_address, blas_implicit.address + clastrace::standin::kImplicitLeadingBytes);
    EXPECT_GT(*blas_size, clastrace::standin::kObjectPaddingBytes);
    EXPECT_LE(*blas_address + *blas_size, blas_implicit.address + blas_implicit.size);
    // The first bytes of the region stay as the application left them.
    EXPECT_EQ(implicit.mapped[0], 0);

    EXPECT_EQ(live_pause_events(), 4u);  // two builds, two events each
    vkFreeCommandBuffers(gpu.device, gpu.pool, 1, &cb);
    EXPECT_EQ(live_pause_events(), 0u);
}

TEST_F(StandinDriver, BuildsClustersAndABottomLevelAtItsOwnLayout) {
    build_at_own_layout(gpu, false);
}

TEST_F(StandinDriver, IndirectedDestinationsAreBuiltAtItsOwnLayoutToo) {
    build_at_own_layout(gpu, true);
}

}  // namespace
