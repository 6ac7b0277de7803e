// SPDX-License-Identifier: Apache-2.0
// A windowed frame loop for the capture layer's frame-range tests: an xcb window on $DISPLAY
// (Xvfb in the tests), a swapchain, and per frame one command buffer that builds triangle
// clusters and a bottom level over them with VK_NV_cluster_acceleration_structure (served by
// the layer on lavapipe), clears the acquired image and presents it.
//   present_frames_app FRAMES [SUBMISSIONS_PER_FRAME]
// Frame f writes clusterID = kFrameIdStride * f + served_scene's ID into srcInfosArray, so a
// trace tells which frames' builds it holds. One frame in flight: the frame's fence is waited
// before the host writes the next frame's inputs; after each frame the app checks the build
// wrote a size for every cluster (the served build ran). Exit 0 when every frame presented,
// 2 on any failure (message on stderr), 3 when the device does not offer the extension.
// SUBMISSIONS_PER_FRAME (default 1) - 1 extra submissions precede each frame's own, each a
// vkCmdFillBuffer of the frame number into 64 bytes of their own: frames and submissions then
// count differently.
#include "cluster_test_device.h"
#include "served_scene.h"

#include <clastrace/vk_cluster_abi.h>
#include <xcb/xcb.h>  // before vulkan_xcb.h, which uses its types
#include <vulkan/vulkan_xcb.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

namespace {

constexpr uint32_t kFrameIdStride = 1000;
constexpr uint64_t kSecond = 1000ull * 1000 * 1000;

using clastrace::testapp::Buffer;
using clastrace::testapp::ClusterTestDevice;
using clastrace::testapp::fail;

struct Window {
    xcb_connection_t* connection = nullptr;
    xcb_window_t window = 0;

    Window() {
        connection = xcb_connect(nullptr, nullptr);  // $DISPLAY
        if (xcb_connection_has_error(connection))
            fail("cannot connect to the X server named by $DISPLAY");
        xcb_screen_t* screen = xcb_setup_roots_iterator(xcb_get_setup(connection)).data;
        window = xcb_generate_id(connection);
        xcb_create_window(connection, XCB_COPY_FROM_PARENT, window, screen->root, 0, 0, 64, 64, 0,
                          XCB_WINDOW_CLASS_INPUT_OUTPUT, screen->root_visual, 0, nullptr);
        xcb_map_window(connection, window);
        xcb_flush(connection);
    }
    ~Window() {
        xcb_destroy_window(connection, window);
        xcb_disconnect(connection);
    }
};

struct App {
    Window window;
    ClusterTestDevice vk;  // its queue also presents to `surface`
    VkSurfaceKHR surface = VK_NULL_HANDLE;
    VkSwapchainKHR swapchain = VK_NULL_HANDLE;
    std::vector<VkImage> images;
    std::vector<VkSemaphore> renderDone;  // one per image: a present may still wait on the last one
    VkSemaphore imageAvailable = VK_NULL_HANDLE;
    VkFence frameDone = VK_NULL_HANDLE;
    VkCommandBuffer cb = VK_NULL_HANDLE;

    void createInstance() {
        vk.createInstance(nullptr,
                          {VK_KHR_SURFACE_EXTENSION_NAME, VK_KHR_XCB_SURFACE_EXTENSION_NAME});
        VkXcbSurfaceCreateInfoKHR surfaceInfo{VK_STRUCTURE_TYPE_XCB_SURFACE_CREATE_INFO_KHR,
                                              nullptr, 0, window.connection, window.window};
        CHECK(vkCreateXcbSurfaceKHR(vk.instance, &surfaceInfo, nullptr, &surface));
    }

    void createSwapchain() {
        VkSurfaceCapabilitiesKHR caps;
        CHECK(vkGetPhysicalDeviceSurfaceCapabilitiesKHR(vk.physicalDevice, surface, &caps));
        uint32_t formatCount = 1;
        VkSurfaceFormatKHR format;
        VkResult r =
            vkGetPhysicalDeviceSurfaceFormatsKHR(vk.physicalDevice, surface, &formatCount, &format);
        if ((r != VK_SUCCESS && r != VK_INCOMPLETE) || formatCount == 0)
            fail("the surface has no format");
        uint32_t modeCount = 0;
        CHECK(vkGetPhysicalDeviceSurfacePresentModesKHR(vk.physicalDevice, surface, &modeCount,
                                                        nullptr));
        std::vector<VkPresentModeKHR> modes(modeCount);
        CHECK(vkGetPhysicalDeviceSurfacePresentModesKHR(vk.physicalDevice, surface, &modeCount,
                                                        modes.data()));
        // Xvfb has no vertical blank to wait for: prefer the modes that never block on one.
        VkPresentModeKHR mode = VK_PRESENT_MODE_FIFO_KHR;
        for (VkPresentModeKHR m : {VK_PRESENT_MODE_MAILBOX_KHR, VK_PRESENT_MODE_IMMEDIATE_KHR})
            if (std::find(modes.begin(), modes.end(), m) != modes.end()) mode = m;
        if (!(caps.supportedUsageFlags & VK_IMAGE_USAGE_TRANSFER_DST_BIT))
            fail("swapchain images cannot be cleared");
        VkSwapchainCreateInfoKHR info{};
        info.sType = VK_STRUCTURE_TYPE_SWAPCHAIN_CREATE_INFO_KHR;
        info.surface = surface;
        info.minImageCount = caps.maxImageCount
                                 ? std::min(caps.minImageCount + 1, caps.maxImageCount)
                                 : caps.minImageCount + 1;
        info.imageFormat = format.format;
        info.imageColorSpace = format.colorSpace;
        info.imageExtent =
            caps.currentExtent.width != UINT32_MAX ? caps.currentExtent : VkExtent2D{64, 64};
        info.imageArrayLayers = 1;
        info.imageUsage = VK_IMAGE_USAGE_TRANSFER_DST_BIT;
        info.imageSharingMode = VK_SHARING_MODE_EXCLUSIVE;
        info.preTransform = caps.currentTransform;
        info.compositeAlpha = VK_COMPOSITE_ALPHA_OPAQUE_BIT_KHR;
        for (VkCompositeAlphaFlagBitsKHR a :
             {VK_COMPOSITE_ALPHA_INHERIT_BIT_KHR, VK_COMPOSITE_ALPHA_OPAQUE_BIT_KHR})
            if (caps.supportedCompositeAlpha & a) info.compositeAlpha = a;
        info.presentMode = mode;
        info.clipped = VK_TRUE;
        CHECK(vkCreateSwapchainKHR(vk.device, &info, nullptr, &swapchain));
        uint32_t imageCount = 0;
        CHECK(vkGetSwapchainImagesKHR(vk.device, swapchain, &imageCount, nullptr));
        images.resize(imageCount);
        CHECK(vkGetSwapchainImagesKHR(vk.device, swapchain, &imageCount, images.data()));
        VkSemaphoreCreateInfo semaphoreInfo{VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO, nullptr, 0};
        renderDone.resize(imageCount);
        for (VkSemaphore& s : renderDone)
            CHECK(vkCreateSemaphore(vk.device, &semaphoreInfo, nullptr, &s));
        CHECK(vkCreateSemaphore(vk.device, &semaphoreInfo, nullptr, &imageAvailable));
        VkFenceCreateInfo fenceInfo{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO, nullptr, 0};
        CHECK(vkCreateFence(vk.device, &fenceInfo, nullptr, &frameDone));
        VkCommandBufferAllocateInfo cbInfo{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO, nullptr,
                                           vk.pool, VK_COMMAND_BUFFER_LEVEL_PRIMARY, 1};
        CHECK(vkAllocateCommandBuffers(vk.device, &cbInfo, &cb));
    }

    void imageBarrier(VkImage image, VkImageLayout from, VkImageLayout to, VkAccessFlags srcAccess,
                      VkAccessFlags dstAccess, VkPipelineStageFlags srcStage,
                      VkPipelineStageFlags dstStage) {
        VkImageMemoryBarrier barrier{VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER,
                                     nullptr,
                                     srcAccess,
                                     dstAccess,
                                     from,
                                     to,
                                     VK_QUEUE_FAMILY_IGNORED,
                                     VK_QUEUE_FAMILY_IGNORED,
                                     image,
                                     {VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1}};
        vkCmdPipelineBarrier(cb, srcStage, dstStage, 0, 0, nullptr, 0, nullptr, 1, &barrier);
    }

    ~App() {
        if (vk.device) {
            vkDeviceWaitIdle(vk.device);
            vkDestroyFence(vk.device, frameDone, nullptr);
            vkDestroySemaphore(vk.device, imageAvailable, nullptr);
            for (VkSemaphore s : renderDone) vkDestroySemaphore(vk.device, s, nullptr);
            vkDestroySwapchainKHR(vk.device, swapchain, nullptr);
        }
        if (surface) vkDestroySurfaceKHR(vk.instance, surface, nullptr);
        vk.destroy();
    }
};

// The served scene's buffers (served_scene.h), its inputs written, and the build commands over
// their addresses.
struct SceneBuffers {
    Buffer vertices, indices, infos, counts, dstAddresses, dstSizes, implicitData, scratch,
        blasInfos, blasDstAddresses, blasDstSizes, blasImplicit, blasScratch;
    served_scene::Inputs in;
    served_scene::Commands commands;
};

void makeScene(App& app, SceneBuffers& b) {
    served_scene::Commands sizing;
    served_scene::makeCommands({}, sizing);
    VkAccelerationStructureBuildSizesInfoKHR clusterSizes{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR, nullptr, 0, 0, 0};
    VkAccelerationStructureBuildSizesInfoKHR blasSizes{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR, nullptr, 0, 0, 0};
    app.vk.getBuildSizes(app.vk.device, &sizing.clusters.input, &clusterSizes);
    app.vk.getBuildSizes(app.vk.device, &sizing.blas.input, &blasSizes);
    if (!clusterSizes.accelerationStructureSize || !blasSizes.accelerationStructureSize)
        fail("build sizes of 0");

    const VkBufferUsageFlags input =
        VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
    const VkBufferUsageFlags storage = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;
    const served_scene::Inputs probe = served_scene::makeInputs({});
    b.vertices = app.vk.makeBuffer(probe.vertices.size() * 4, input);
    b.indices = app.vk.makeBuffer(probe.indices.size() * 4, input);
    b.infos = app.vk.makeBuffer(served_scene::kInfoStride * served_scene::kMaxClusters, input);
    b.counts = app.vk.makeBuffer(8, input);
    b.dstAddresses = app.vk.makeBuffer(8 * served_scene::kMaxClusters, storage | input);
    b.dstSizes = app.vk.makeBuffer(4 * served_scene::kMaxClusters, storage);
    b.implicitData = app.vk.makeBuffer(clusterSizes.accelerationStructureSize, storage);
    b.scratch = app.vk.makeBuffer(clusterSizes.buildScratchSize, 0);
    b.blasInfos =
        app.vk.makeBuffer(sizeof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV),
                          input);
    b.blasDstAddresses = app.vk.makeBuffer(8, storage);
    b.blasDstSizes = app.vk.makeBuffer(4, storage);
    b.blasImplicit = app.vk.makeBuffer(blasSizes.accelerationStructureSize, storage);
    b.blasScratch = app.vk.makeBuffer(blasSizes.buildScratchSize, 0);
    const served_scene::Addresses a{b.vertices.address,     b.indices.address,
                                    b.infos.address,        b.counts.address,
                                    b.dstAddresses.address, b.dstSizes.address,
                                    b.implicitData.address, b.scratch.address,
                                    b.blasInfos.address,    b.blasDstAddresses.address,
                                    b.blasDstSizes.address, b.blasImplicit.address,
                                    b.blasScratch.address};
    b.in = served_scene::makeInputs(a);
    std::memcpy(b.vertices.mapped, b.in.vertices.data(), b.in.vertices.size() * 4);
    std::memcpy(b.indices.mapped, b.in.indices.data(), b.in.indices.size() * 4);
    std::memcpy(b.counts.mapped, b.in.counts, sizeof b.in.counts);
    std::memcpy(b.blasInfos.mapped, &b.in.blasInfo, sizeof b.in.blasInfo);
    served_scene::makeCommands(a, b.commands);
}

// The previous frame's fence was waited: the host may rewrite the build's inputs.
void writeFrameInputs(SceneBuffers& b, uint32_t frame) {
    for (uint32_t c = 0; c < served_scene::kClusterCount; ++c) {
        auto info = b.in.infos[c];
        info.clusterID += kFrameIdStride * frame;
        std::memcpy(b.infos.mapped + c * served_scene::kInfoStride, &info, sizeof info);
    }
    std::memset(b.dstSizes.mapped, 0, 4 * served_scene::kMaxClusters);
}

// Submissions before the frame's own: a fill each, 64 bytes apart (no barrier needed between).
void submitExtraFills(App& app, const std::vector<VkCommandBuffer>& extra, const Buffer& fillTarget,
                      uint32_t frame) {
    for (size_t k = 0; k < extra.size(); ++k) {
        VkCommandBuffer e = extra[k];
        VkCommandBufferBeginInfo once{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO, nullptr,
                                      VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT, nullptr};
        CHECK(vkBeginCommandBuffer(e, &once));
        vkCmdFillBuffer(e, fillTarget.buffer, 64 * k, 64, frame);
        CHECK(vkEndCommandBuffer(e));
        VkSubmitInfo fill{
            VK_STRUCTURE_TYPE_SUBMIT_INFO, nullptr, 0, nullptr, nullptr, 1, &e, 0, nullptr};
        CHECK(vkQueueSubmit(app.vk.queue, 1, &fill, VK_NULL_HANDLE));
    }
}

// The builds, then the swapchain image cleared to a colour per frame (the window shows the
// loop advancing).
void recordFrame(App& app, const SceneBuffers& b, uint32_t image, uint32_t frame) {
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO, nullptr,
                                   VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT, nullptr};
    CHECK(vkBeginCommandBuffer(app.cb, &begin));
    app.vk.cmdBuildClusters(app.cb, &b.commands.clusters);
    VkMemoryBarrier built{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                          VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                          VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                              VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_INDIRECT_COMMAND_READ_BIT};
    vkCmdPipelineBarrier(app.cb, VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                         VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR, 0, 1, &built, 0,
                         nullptr, 0, nullptr);
    app.vk.cmdBuildClusters(app.cb, &b.commands.blas);
    VkMemoryBarrier toHost{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                           VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR, VK_ACCESS_HOST_READ_BIT};
    vkCmdPipelineBarrier(app.cb, VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                         VK_PIPELINE_STAGE_HOST_BIT, 0, 1, &toHost, 0, nullptr, 0, nullptr);
    app.imageBarrier(app.images[image], VK_IMAGE_LAYOUT_UNDEFINED,
                     VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 0, VK_ACCESS_TRANSFER_WRITE_BIT,
                     VK_PIPELINE_STAGE_TRANSFER_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT);
    const VkClearColorValue color{{float(frame % 3) / 2.0f, 0.25f, 0.5f, 1.0f}};
    const VkImageSubresourceRange whole{VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1};
    vkCmdClearColorImage(app.cb, app.images[image], VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, &color, 1,
                         &whole);
    app.imageBarrier(app.images[image], VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                     VK_IMAGE_LAYOUT_PRESENT_SRC_KHR, VK_ACCESS_TRANSFER_WRITE_BIT, 0,
                     VK_PIPELINE_STAGE_TRANSFER_BIT, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT);
    CHECK(vkEndCommandBuffer(app.cb));
}

// Submits the frame (waiting for its image, signalling its render-done semaphore) and presents
// it; false when the present failed.
bool submitAndPresent(App& app, uint32_t image, uint32_t frame) {
    const VkPipelineStageFlags waitStage = VK_PIPELINE_STAGE_TRANSFER_BIT;
    VkSubmitInfo submit{
        VK_STRUCTURE_TYPE_SUBMIT_INFO, nullptr, 1, &app.imageAvailable, &waitStage, 1, &app.cb, 1,
        &app.renderDone[image]};
    CHECK(vkQueueSubmit(app.vk.queue, 1, &submit, app.frameDone));
    VkPresentInfoKHR present{VK_STRUCTURE_TYPE_PRESENT_INFO_KHR,
                             nullptr,
                             1,
                             &app.renderDone[image],
                             1,
                             &app.swapchain,
                             &image,
                             nullptr};
    const VkResult presented = vkQueuePresentKHR(app.vk.queue, &present);
    if (presented != VK_SUCCESS && presented != VK_SUBOPTIMAL_KHR) {
        std::fprintf(stderr, "present_frames_app: vkQueuePresentKHR of frame %u failed: %d\n",
                     frame, int(presented));
        return false;
    }
    return true;
}

// After the frame's fence: every cluster of the frame was built (its size is not 0).
bool everyClusterBuilt(const SceneBuffers& b, uint32_t frame) {
    for (uint32_t c = 0; c < served_scene::kClusterCount; ++c) {
        uint32_t size = 0;
        std::memcpy(&size, b.dstSizes.mapped + 4 * c, 4);
        if (size == 0) {
            std::fprintf(
                stderr,
                "present_frames_app: frame %u: cluster %u was not built (dstSizesArray is 0)\n",
                frame, c);
            return false;
        }
    }
    return true;
}

int run(uint32_t frames, uint32_t submissionsPerFrame) {
    App app;
    app.createInstance();
    if (!app.vk.hasClusterExtension()) {
        std::printf("VK_NV_cluster_acceleration_structure is not supported\n");
        return 3;
    }
    app.vk.createDevice(false, 1, app.surface);
    app.createSwapchain();
    SceneBuffers scene;
    makeScene(app, scene);
    Buffer fillTarget = app.vk.makeBuffer(64 * 16, VK_BUFFER_USAGE_TRANSFER_DST_BIT);
    std::vector<VkCommandBuffer> extra(submissionsPerFrame - 1);
    if (!extra.empty()) {
        VkCommandBufferAllocateInfo extraInfo{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO,
                                              nullptr, app.vk.pool, VK_COMMAND_BUFFER_LEVEL_PRIMARY,
                                              uint32_t(extra.size())};
        CHECK(vkAllocateCommandBuffers(app.vk.device, &extraInfo, extra.data()));
    }
    for (uint32_t frame = 0; frame < frames; ++frame) {
        writeFrameInputs(scene, frame);
        submitExtraFills(app, extra, fillTarget, frame);
        uint32_t image = 0;
        CHECK(vkAcquireNextImageKHR(app.vk.device, app.swapchain, 10 * kSecond, app.imageAvailable,
                                    VK_NULL_HANDLE, &image));
        recordFrame(app, scene, image, frame);
        if (!submitAndPresent(app, image, frame)) return 2;
        CHECK(vkWaitForFences(app.vk.device, 1, &app.frameDone, VK_TRUE, 30 * kSecond));
        CHECK(vkResetFences(app.vk.device, 1, &app.frameDone));
        if (!everyClusterBuilt(scene, frame)) return 2;
    }
    std::printf("presented %u frames\n", frames);
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    const int frames = argc >= 2 ? std::atoi(argv[1]) : 0;
    const int submissions = argc == 3 ? std::atoi(argv[2]) : 1;
    if (argc > 3 || frames <= 0 || frames > 10000 || submissions <= 0 || submissions > 16) {
        std::fprintf(stderr,
                     "usage: present_frames_app FRAMES [SUBMISSIONS_PER_FRAME]   (1..10000, 1..16; "
                     "the window "
                     "goes to $DISPLAY)\n");
        return 1;
    }
    return run(uint32_t(frames), uint32_t(submissions));
}
