// SPDX-License-Identifier: Apache-2.0
#include "cluster_scene.h"

#include "copy_words_spirv.h"  // kCopyWordsSpirv: shaders/copy_words.comp, compiled at build time

#include <clastrace/common/hex.h>

#include <algorithm>
#include <cstring>
#include <deque>
#include <memory>
#include <stdexcept>

namespace cluster_scene {
namespace {

// Every build shares one scratch buffer, so consecutive builds are separated by a barrier
// that makes the earlier scratch writes available before the later build writes scratch
// again (write-after-write). The same barrier carries the data dependencies on earlier builds:
// its first scope holds every earlier build, so one barrier per build suffices.
constexpr VkAccessFlags kBuildWrites = VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;
constexpr VkAccessFlags kBuildReads =
    VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR | VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR |
    VK_ACCESS_INDIRECT_COMMAND_READ_BIT | VK_ACCESS_SHADER_READ_BIT;
constexpr VkPipelineStageFlags kBuildStage = VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;

const VkBufferUsageFlags kInput =
    VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
const VkBufferUsageFlags kStorage = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;

}  // namespace

const std::vector<BarrierInfo>& barrierCatalogue(bool computeInfos) {
    static const std::vector<BarrierInfo> copied = {
        // Both cluster builds read the copied infos; the barrier between them orders builds only.
        {"copy-to-sizes",
         "copy:cluster-infos -> build:cluster-sizes, build:clusters: the copied srcInfosArray and "
         "count"},
        {"sizes-to-clusters", "build:cluster-sizes -> build:clusters: scratch reuse"},
        {"copy-to-templates",
         "copy:template-infos -> build:templates, build:template-move: the copied srcInfosArray "
         "and count"},
        {"clusters-to-templates", "build:clusters -> build:templates: scratch reuse"},
        {"templates-to-template-move",
         "build:templates -> build:template-move: template addresses and objects, scratch reuse"},
        {"template-move-to-address-copy",
         "build:template-move -> copy:template-addresses: the moved template addresses it wrote"},
        {"copy-to-instantiate",
         "copy:instance-infos, copy:template-addresses -> build:instantiate: the copied "
         "srcInfosArray and count"},
        // The moved templates already reach the instantiation through the chain
        // template-move-to-address-copy -> copy-to-instantiate; this one adds scratch reuse.
        {"template-move-to-instantiate", "build:template-move -> build:instantiate: scratch reuse"},
        {"instantiate-to-indices", "build:instantiate -> build:template-indices: scratch reuse"},
        {"indices-to-move", "build:template-indices -> build:move: scratch reuse"},
        {"copy-to-blas", "copy:blas-infos -> build:blas: the copied srcInfosArray and count"},
        {"move-to-blas",
         "build:move -> build:blas: moved cluster addresses and objects, scratch reuse"},
    };
    // --compute-infos: compute dispatches write the cluster infos, so dispatch-to-sizes takes
    // copy-to-sizes' place; the rest is the same.
    static const std::vector<BarrierInfo> computed = [] {
        std::vector<BarrierInfo> barriers = copied;
        barriers.front() = {"dispatch-to-sizes",
                            "dispatch:cluster-infos -> build:cluster-sizes, build:clusters: the "
                            "srcInfosArray and count a compute shader wrote through buffer device "
                            "addresses"};
        return barriers;
    }();
    return computeInfos ? computed : copied;
}

uint64_t fnv1a64(const uint8_t* data, size_t size) {
    uint64_t h = 0xcbf29ce484222325ull;
    for (size_t i = 0; i < size; ++i) h = (h ^ data[i]) * 0x100000001b3ull;
    return h;
}

namespace {

std::string hex(const uint8_t* data, size_t size) {
    return clastrace::common::hex_bytes({data, size});
}

// One vkCmdBuildClusterAccelerationStructureIndirectNV with its output buffers. `info`
// points into the object itself, so commands live in a deque and never move.
struct ClusterCommand {
    std::string label;
    uint32_t ops = 0;
    VkClusterAccelerationStructureTriangleClusterInputNV triangles{};
    VkClusterAccelerationStructureClustersBottomLevelInputNV bottomLevel{};
    VkClusterAccelerationStructureMoveObjectsInputNV move{};
    VkClusterAccelerationStructureCommandsInfoNV info{};
    Buffer addresses, sizes, implicitData;
};

// Offsets of the src infos and counts, the same in the staging buffer and the infos buffer.
struct InfoLayout {
    VkDeviceSize clusters = 0, templates = 0, instances = 0, blas = 0, counts = 0, size = 0;
    static constexpr VkDeviceSize kClusterCount = 0, kTemplateCount = 16, kInstanceCount = 32,
                                  kBlasCount = 48;
};

VkDeviceSize align(VkDeviceSize v, VkDeviceSize a) { return (v + a - 1) / a * a; }

class SceneRecorder {
public:
    SceneRecorder(VulkanContext& context, const ClusteredMesh& mesh, const SceneOptions& options)
        : c_(context), mesh_(mesh), options_(options), n_(uint32_t(mesh.clusters.size())) {}

    ~SceneRecorder() {
        for (Buffer* b : ownedBuffers()) c_.destroyBuffer(*b);
        for (auto& command : commands_)
            for (Buffer* b : {&command.addresses, &command.sizes, &command.implicitData})
                c_.destroyBuffer(*b);
        if (pool_) vkDestroyCommandPool(c_.device(), pool_, nullptr);
        if (copyPipeline_) vkDestroyPipeline(c_.device(), copyPipeline_, nullptr);
        if (copyLayout_) vkDestroyPipelineLayout(c_.device(), copyLayout_, nullptr);
    }

    SceneResult run() {
        if (n_ == 0) throw std::runtime_error("the mesh has no cluster to build");
        createInputs();
        defineCommands();
        if (options_.computeInfos) createCopyPipeline();
        if (options_.beforeRecording) options_.beforeRecording();
        record();
        c_.submitAndWait(cb_, options_.queueIndex);
        readBack();
        return std::move(result_);
    }

private:
    std::vector<Buffer*> ownedBuffers() {
        return {&vertices_, &indices_, &instanceVertices_, &staging_,
                &infos_,    &scratch_, &elsewhere_};
    }

    void createInputs() {
        vertices_ = c_.createBuffer(mesh_.positions.size() * 4, kInput, 16);
        std::memcpy(vertices_.mapped, mesh_.positions.data(), mesh_.positions.size() * 4);
        // The instances: the same clusters one mesh-width to the right.
        float minX = mesh_.positions[0], maxX = mesh_.positions[0];
        for (size_t i = 0; i < mesh_.positions.size(); i += 3)
            minX = std::min(minX, mesh_.positions[i]), maxX = std::max(maxX, mesh_.positions[i]);
        std::vector<float> moved = mesh_.positions;
        for (size_t i = 0; i < moved.size(); i += 3) moved[i] += (maxX - minX) * 1.25f + 1.0f;
        instanceVertices_ = c_.createBuffer(moved.size() * 4, kInput, 16);
        std::memcpy(instanceVertices_.mapped, moved.data(), moved.size() * 4);
        indices_ = c_.createBuffer(mesh_.indices.size(), kInput, 16);
        std::memcpy(indices_.mapped, mesh_.indices.data(), mesh_.indices.size());

        layout_.clusters = 0;
        layout_.templates =
            align(layout_.clusters +
                      n_ * sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV),
                  64);
        layout_.instances =
            align(layout_.templates +
                      n_ * sizeof(VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV),
                  64);
        layout_.blas =
            align(layout_.instances +
                      n_ * sizeof(VkClusterAccelerationStructureInstantiateClusterInfoNV),
                  64);
        layout_.counts =
            align(layout_.blas +
                      2 * sizeof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV),
                  64);
        layout_.size = layout_.counts + 64;
        staging_ = c_.createBuffer(layout_.size, 0, 64);
        // 0xEE: what a build would read if a copy had not landed yet is visibly not an info.
        infos_ =
            c_.createBuffer(layout_.size, kInput | VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 64, 0xEE);
        if (options_.computeInfos && options_.computeElsewhere)
            elsewhere_ = c_.createBuffer(layout_.size, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 64);
    }

    ClusterCommand& addCommand(const char* label, VkClusterAccelerationStructureOpTypeNV type,
                               VkClusterAccelerationStructureOpModeNV mode, uint32_t ops,
                               VkDeviceSize infos, VkDeviceSize infoStride, VkDeviceAddress count) {
        ClusterCommand& cmd = commands_.emplace_back();
        cmd.label = label;
        cmd.ops = ops;
        VkClusterAccelerationStructureCommandsInfoNV& info = cmd.info;
        info.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
        info.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
        info.input.maxAccelerationStructureCount = ops;
        info.input.opType = type;
        info.input.opMode = mode;
        if (type == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV) {
            cmd.bottomLevel.sType =
                VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_CLUSTERS_BOTTOM_LEVEL_INPUT_NV;
            cmd.bottomLevel.maxTotalClusterCount = 2 * n_;
            cmd.bottomLevel.maxClusterCountPerAccelerationStructure = n_;
            info.input.opInput.pClustersBottomLevel = &cmd.bottomLevel;
        } else if (type == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV) {
            cmd.move.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_MOVE_OBJECTS_INPUT_NV;
            // Moves compact what an earlier build packed: at most all of its bytes move.
            const bool templates = std::string(label) == "template-move";
            cmd.move.type =
                templates ? VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_TEMPLATE_NV
                          : VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_NV;
            cmd.move.noMoveOverlap = VK_TRUE;
            cmd.move.maxMovedBytes = (templates ? templates_ : clusters_)->implicitData.size;
            info.input.opInput.pMoveObjects = &cmd.move;
        } else {
            cmd.triangles.sType =
                VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
            cmd.triangles.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
            cmd.triangles.maxGeometryIndexValue = 0;
            cmd.triangles.maxClusterUniqueGeometryCount = 1;
            cmd.triangles.maxClusterTriangleCount = mesh_.maxClusterTriangles;
            cmd.triangles.maxClusterVertexCount = mesh_.maxClusterVertices;
            cmd.triangles.maxTotalTriangleCount = mesh_.totalTriangles();
            cmd.triangles.maxTotalVertexCount = mesh_.totalVertices();
            info.input.opInput.pTriangleClusters = &cmd.triangles;
        }
        VkAccelerationStructureBuildSizesInfoKHR sizes{
            VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR, nullptr, 0, 0, 0};
        c_.getBuildSizes(c_.device(), &info.input, &sizes);
        if (mode != VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV &&
            sizes.accelerationStructureSize == 0)
            throw std::runtime_error(
                std::string("vkGetClusterAccelerationStructureBuildSizesNV gave 0 bytes for ") +
                label);
        scratchSize_ = std::max(scratchSize_, sizes.buildScratchSize);
        const auto& p = c_.clusterProperties();
        const VkDeviceSize objectAlignment =
            std::max({p.clusterByteAlignment, p.clusterBottomLevelByteAlignment,
                      p.clusterTemplateByteAlignment, 16u});
        cmd.sizes = c_.createBuffer(4ull * ops, kStorage | kInput, 16);
        info.dstSizesArray = {cmd.sizes.address, 4, 4ull * ops};
        if (mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV) {
            cmd.implicitData =
                c_.createBuffer(sizes.accelerationStructureSize, kStorage, objectAlignment);
            // Read by later builds as src infos or cluster references.
            cmd.addresses =
                c_.createBuffer(8ull * ops, kStorage | kInput | VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
                                16);
            info.dstImplicitData = cmd.implicitData.address;
            info.dstAddressesArray = {cmd.addresses.address, 8, 8ull * ops};
        }
        info.srcInfosArray = {infos, infoStride, infoStride * ops};
        info.srcInfosCount = count;
        return cmd;
    }

    void defineCommands() {
        // Staging: the infos as the host computes them; the GPU copies them into infos_.
        uint8_t* s = staging_.mapped;
        for (uint32_t i = 0; i < n_; ++i) {
            const MeshCluster& cl = mesh_.clusters[i];
            VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV t{};
            t.clusterID = i;
            t.triangleCount = cl.triangleCount;
            t.vertexCount = cl.vertexCount;
            t.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_8BIT_NV;
            t.baseGeometryIndexAndGeometryFlags.geometryFlags =
                VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_OPAQUE_BIT_NV;
            t.indexBufferStride = 1;
            t.vertexBufferStride = 12;
            t.indexBuffer = indices_.address + cl.firstIndex;
            t.vertexBuffer = vertices_.address + 12ull * cl.firstVertex;
            std::memcpy(s + layout_.clusters +
                            i * sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV),
                        &t, sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV));
            std::memcpy(s + layout_.templates + i * sizeof t, &t, sizeof t);
            VkClusterAccelerationStructureInstantiateClusterInfoNV instance{};
            instance.clusterIdOffset = 1000;
            instance.clusterTemplateAddress = 0;  // the GPU copies the template's address here
            instance.vertexBuffer = {instanceVertices_.address + 12ull * cl.firstVertex, 12};
            std::memcpy(s + layout_.instances + i * sizeof instance, &instance, sizeof instance);
        }
        const uint32_t counts[4] = {n_, n_, n_, 2};
        const VkDeviceSize countOffsets[4] = {InfoLayout::kClusterCount, InfoLayout::kTemplateCount,
                                              InfoLayout::kInstanceCount, InfoLayout::kBlasCount};
        for (int i = 0; i < 4; ++i)
            std::memcpy(s + layout_.counts + countOffsets[i], &counts[i], 4);

        const VkDeviceAddress infos = infos_.address;
        const VkDeviceAddress countAt = infos + layout_.counts;
        const auto type = [](int t) { return VkClusterAccelerationStructureOpTypeNV(t); };
        const auto implicit = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
        sizes_ =
            &addCommand("cluster-sizes",
                        type(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV),
                        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV, n_,
                        infos + layout_.clusters,
                        sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV),
                        countAt + InfoLayout::kClusterCount);
        clusters_ =
            &addCommand("clusters",
                        type(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV),
                        implicit, n_, infos + layout_.clusters,
                        sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV),
                        countAt + InfoLayout::kClusterCount);
        templates_ = &addCommand(
            "templates",
            type(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV),
            implicit, n_, infos + layout_.templates,
            sizeof(VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV),
            countAt + InfoLayout::kTemplateCount);
        instantiate_ = &addCommand(
            "instantiate",
            type(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV),
            implicit, n_, infos + layout_.instances,
            sizeof(VkClusterAccelerationStructureInstantiateClusterInfoNV),
            countAt + InfoLayout::kInstanceCount);
        // Template indices and moves read the addresses earlier builds wrote as their src infos
        // (both info structs are one VkDeviceAddress): no copy needed. The templates are moved
        // (compacted) before anything uses them.
        templateMove_ =
            &addCommand("template-move",
                        type(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV), implicit,
                        n_, templates_->addresses.address, 8, countAt + InfoLayout::kTemplateCount);
        templateIndices_ = &addCommand(
            "template-indices",
            type(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV),
            implicit, n_, templateMove_->addresses.address, 8,
            countAt + InfoLayout::kTemplateCount);
        move_ = &addCommand("move", type(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV),
                            implicit, n_, clusters_->addresses.address, 8,
                            countAt + InfoLayout::kClusterCount);
        blas_ = &addCommand(
            "blas", type(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV),
            implicit, 2, infos + layout_.blas,
            sizeof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV),
            countAt + InfoLayout::kBlasCount);
        // One bottom level over the moved clusters, one over the instantiated ones.
        VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV blas[2] = {
            {n_, 8, move_->addresses.address}, {n_, 8, instantiate_->addresses.address}};
        std::memcpy(s + layout_.blas, blas, sizeof blas);

        const auto& p = c_.clusterProperties();
        scratch_ = c_.createBuffer(scratchSize_, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
                                   std::max(p.clusterScratchByteAlignment, 16u));
        for (auto& command : commands_) command.info.scratchData = scratch_.address;
    }

    // --- recording ---------------------------------------------------------------------

    void copy(const char* label, const Buffer& from, const Buffer& to,
              std::vector<VkBufferCopy> regions) {
        for (auto& r : regions) r.srcOffset += from.offset, r.dstOffset += to.offset;
        vkCmdCopyBuffer(cb_, from.buffer, to.buffer, uint32_t(regions.size()), regions.data());
        result_.commands.push_back(std::string("copy:") + label);
        ++result_.copies;
    }
    // Copies staging bytes [offset, offset + size) to the same offsets of infos_, and the count.
    void copyInfos(const char* label, VkDeviceSize offset, VkDeviceSize size,
                   VkDeviceSize countOffset) {
        copy(label, staging_, infos_,
             {{offset, offset, size},
              {layout_.counts + countOffset, layout_.counts + countOffset, 4}});
    }

    // The compute pipeline of shaders/copy_words.comp: four device addresses and a word count
    // in push constants, no descriptor.
    struct CopyWordsConstants {
        VkDeviceAddress source, target, countSource, countTarget;
        uint32_t words;
    };
    void createCopyPipeline() {
        VkShaderModuleCreateInfo moduleInfo{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO, nullptr, 0,
                                            sizeof kCopyWordsSpirv, kCopyWordsSpirv};
        VkShaderModule module = VK_NULL_HANDLE;
        CLUSTER_SCENE_CHECK(vkCreateShaderModule(c_.device(), &moduleInfo, nullptr, &module));
        const VkPushConstantRange range{VK_SHADER_STAGE_COMPUTE_BIT, 0,
                                        uint32_t(sizeof(CopyWordsConstants))};
        VkPipelineLayoutCreateInfo layoutInfo{
            VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO, nullptr, 0, 0, nullptr, 1, &range};
        CLUSTER_SCENE_CHECK(
            vkCreatePipelineLayout(c_.device(), &layoutInfo, nullptr, &copyLayout_));
        VkComputePipelineCreateInfo pipelineInfo{};
        pipelineInfo.sType = VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO;
        pipelineInfo.stage = {VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO,
                              nullptr,
                              0,
                              VK_SHADER_STAGE_COMPUTE_BIT,
                              module,
                              "main",
                              nullptr};
        pipelineInfo.layout = copyLayout_;
        const VkResult created = vkCreateComputePipelines(c_.device(), VK_NULL_HANDLE, 1,
                                                          &pipelineInfo, nullptr, &copyPipeline_);
        vkDestroyShaderModule(c_.device(), module, nullptr);
        CLUSTER_SCENE_CHECK(created);
    }
    // Copies staging bytes [offset, offset + size) and the 4-byte count at countOffset to the
    // same offsets of infos_ with one dispatch that reaches them only through device addresses.
    void dispatchCopy(const char* label, const Buffer& target, VkDeviceSize offset,
                      VkDeviceSize size, VkDeviceSize countOffset) {
        const CopyWordsConstants constants{staging_.address + offset, target.address + offset,
                                           staging_.address + countOffset,
                                           target.address + countOffset, uint32_t(size / 4)};
        vkCmdBindPipeline(cb_, VK_PIPELINE_BIND_POINT_COMPUTE, copyPipeline_);
        vkCmdPushConstants(cb_, copyLayout_, VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof constants,
                           &constants);
        vkCmdDispatch(cb_, (constants.words + 63) / 64, 1, 1);
        result_.computeWrites.push_back({constants.target, size});
        result_.computeWrites.push_back({constants.countTarget, 4});
        result_.commands.push_back(std::string("dispatch:") + label);
        ++result_.dispatches;
    }

    void barrier(const char* name, VkPipelineStageFlags srcStage, VkAccessFlags srcAccess,
                 VkPipelineStageFlags dstStage, VkAccessFlags dstAccess) {
        if (options_.skipBarriers.count(name)) return;
        VkMemoryBarrier b{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, srcAccess, dstAccess};
        vkCmdPipelineBarrier(cb_, srcStage, dstStage, 0, 1, &b, 0, nullptr, 0, nullptr);
        result_.commands.push_back(std::string("barrier:") + name);
        ++result_.barriers;
    }
    void copyToBuild(const char* name) {
        barrier(name, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT, kBuildStage,
                VK_ACCESS_INDIRECT_COMMAND_READ_BIT |
                    VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR);
    }
    void buildToBuild(const char* name) {
        barrier(name, kBuildStage, kBuildWrites, kBuildStage, kBuildReads);
    }

    void build(ClusterCommand& command) {
        c_.cmdBuildClusters(cb_, &command.info);
        recorded_.push_back(&command);
        result_.commands.push_back("build:" + command.label);
        ++result_.builds;
    }

    void record() {
        VkCommandPoolCreateInfo poolInfo{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO, nullptr, 0,
                                         c_.queueFamily()};
        CLUSTER_SCENE_CHECK(vkCreateCommandPool(c_.device(), &poolInfo, nullptr, &pool_));
        VkCommandBufferAllocateInfo allocate{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO,
                                             nullptr, pool_, VK_COMMAND_BUFFER_LEVEL_PRIMARY, 1};
        CLUSTER_SCENE_CHECK(vkAllocateCommandBuffers(c_.device(), &allocate, &cb_));
        result_.commandBuffer = uint64_t(cb_);
        VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO, nullptr,
                                       VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT, nullptr};
        CLUSTER_SCENE_CHECK(vkBeginCommandBuffer(cb_, &begin));

        const VkDeviceSize clusterInfos =
            n_ * sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV);
        const VkDeviceSize templateInfos =
            n_ * sizeof(VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV);
        constexpr VkDeviceSize kInstance =
            sizeof(VkClusterAccelerationStructureInstantiateClusterInfoNV);

        if (options_.computeInfos) {
            dispatchCopy("cluster-infos", infos_, layout_.clusters, clusterInfos,
                         layout_.counts + InfoLayout::kClusterCount);
            barrier("dispatch-to-sizes", VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                    VK_ACCESS_SHADER_WRITE_BIT, kBuildStage,
                    VK_ACCESS_INDIRECT_COMMAND_READ_BIT |
                        VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR);
            if (options_.computeElsewhere)  // no barrier: nothing reads what it writes
                dispatchCopy("cluster-infos-elsewhere", elsewhere_, layout_.clusters, clusterInfos,
                             layout_.counts + InfoLayout::kClusterCount);
        } else {
            copyInfos("cluster-infos", layout_.clusters, clusterInfos, InfoLayout::kClusterCount);
            copyToBuild("copy-to-sizes");
        }
        build(*sizes_);
        buildToBuild("sizes-to-clusters");
        build(*clusters_);

        copyInfos("template-infos", layout_.templates, templateInfos, InfoLayout::kTemplateCount);
        copyToBuild("copy-to-templates");
        buildToBuild("clusters-to-templates");
        build(*templates_);
        buildToBuild("templates-to-template-move");
        build(*templateMove_);

        // Instance infos: everything but clusterTemplateAddress from staging, then each
        // moved template's address from the template move's dstAddressesArray.
        std::vector<VkBufferCopy> fromStaging, fromTemplates;
        constexpr VkDeviceSize kTemplateField =
            offsetof(VkClusterAccelerationStructureInstantiateClusterInfoNV,
                     clusterTemplateAddress);
        for (uint32_t i = 0; i < n_; ++i) {
            const VkDeviceSize at = layout_.instances + i * kInstance;
            fromStaging.push_back({at, at, kTemplateField});
            fromStaging.push_back(
                {at + kTemplateField + 8, at + kTemplateField + 8, kInstance - kTemplateField - 8});
            fromTemplates.push_back({8ull * i, at + kTemplateField, 8});
        }
        const VkDeviceSize countAt = layout_.counts + InfoLayout::kInstanceCount;
        fromStaging.push_back({countAt, countAt, 4});
        copy("instance-infos", staging_, infos_, fromStaging);
        barrier("template-move-to-address-copy", kBuildStage, kBuildWrites,
                VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_READ_BIT);
        copy("template-addresses", templateMove_->addresses, infos_, fromTemplates);
        copyToBuild("copy-to-instantiate");
        buildToBuild("template-move-to-instantiate");
        build(*instantiate_);

        buildToBuild("instantiate-to-indices");
        build(*templateIndices_);
        buildToBuild("indices-to-move");
        build(*move_);

        copyInfos("blas-infos", layout_.blas,
                  2 * sizeof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV),
                  InfoLayout::kBlasCount);
        copyToBuild("copy-to-blas");
        buildToBuild("move-to-blas");
        build(*blas_);

        // The host reads every output after the fence: not optional, so not in the catalogue.
        VkMemoryBarrier toHost{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, kBuildWrites,
                               VK_ACCESS_HOST_READ_BIT};
        vkCmdPipelineBarrier(cb_, kBuildStage, VK_PIPELINE_STAGE_HOST_BIT, 0, 1, &toHost, 0,
                             nullptr, 0, nullptr);
        result_.commands.push_back("barrier:builds-to-host");
        ++result_.barriers;
        CLUSTER_SCENE_CHECK(vkEndCommandBuffer(cb_));
    }

    void readBack() {
        for (ClusterCommand* recorded : recorded_) {  // in record order, as the trace lists them
            const ClusterCommand& command = *recorded;
            BuildOutputs out;
            out.label = command.label;
            out.opType = command.info.input.opType;
            out.opMode = command.info.input.opMode;
            out.ops = command.ops;
            out.dstAddressesArray = command.info.dstAddressesArray.deviceAddress;
            out.dstSizesArray = command.info.dstSizesArray.deviceAddress;
            out.dstImplicitData = command.info.dstImplicitData;
            out.sizes.resize(command.ops);
            std::memcpy(out.sizes.data(), command.sizes.mapped, 4ull * command.ops);
            out.sizesHex = hex(command.sizes.mapped, 4ull * command.ops);
            if (command.addresses.buffer) {
                out.addresses.resize(command.ops);
                std::memcpy(out.addresses.data(), command.addresses.mapped, 8ull * command.ops);
                out.addressesHex = hex(command.addresses.mapped, 8ull * command.ops);
                const Buffer& data = command.implicitData;
                for (uint32_t i = 0; i < command.ops; ++i) {
                    const uint64_t at = out.addresses[i];
                    if (at < data.address || at - data.address > data.size ||
                        data.size - (at - data.address) < out.sizes[i])
                        throw std::runtime_error(
                            "build:" + command.label + " op " + std::to_string(i) +
                            " wrote address " + std::to_string(at) + " of " +
                            std::to_string(out.sizes[i]) + " bytes outside its dstImplicitData");
                    out.objectDigests.push_back(
                        fnv1a64(data.mapped + (at - data.address), out.sizes[i]));
                }
            }
            result_.outputs.push_back(std::move(out));
        }
    }

    VulkanContext& c_;
    const ClusteredMesh& mesh_;
    const SceneOptions& options_;
    const uint32_t n_;
    InfoLayout layout_;
    Buffer vertices_, indices_, instanceVertices_, staging_, infos_, scratch_;
    Buffer elsewhere_;  // --compute-elsewhere: written, never read
    VkDeviceSize scratchSize_ = 0;
    std::deque<ClusterCommand> commands_;
    std::vector<ClusterCommand*> recorded_;
    ClusterCommand *sizes_ = nullptr, *clusters_ = nullptr, *templates_ = nullptr,
                   *templateMove_ = nullptr, *instantiate_ = nullptr, *templateIndices_ = nullptr,
                   *move_ = nullptr, *blas_ = nullptr;
    VkCommandPool pool_ = VK_NULL_HANDLE;
    VkPipelineLayout copyLayout_ = VK_NULL_HANDLE;
    VkPipeline copyPipeline_ = VK_NULL_HANDLE;
    VkCommandBuffer cb_ = VK_NULL_HANDLE;
    SceneResult result_;
};

}  // namespace

SceneResult runScene(VulkanContext& context, const ClusteredMesh& mesh,
                     const SceneOptions& options) {
    for (const std::string& name : options.skipBarriers) {
        const auto& all = barrierCatalogue(options.computeInfos);
        if (std::none_of(all.begin(), all.end(),
                         [&](const BarrierInfo& b) { return name == b.name; }))
            throw std::runtime_error("no barrier is named '" + name +
                                     "' (--list-barriers prints the names)");
    }
    SceneRecorder recorder(context, mesh, options);
    return recorder.run();
}

}  // namespace cluster_scene
