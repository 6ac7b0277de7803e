// SPDX-License-Identifier: Apache-2.0
/* The command forms of VK_KHR_maintenance6 (registered extension 546, revision 1) that bind and
 * push descriptors and push constants, declared for Vulkan headers that predate it (Debian 12's
 * 1.3.239). Lavapipe 25 exposes the extension; the capture layer follows these commands as their
 * 1.0 forms (capture/README.md, "Consumers of acceleration structures"). When the installed
 * header already declares the extension, its declarations are used. */
#pragma once

#include <vulkan/vulkan_core.h>

#ifndef VK_KHR_maintenance6
#define VK_KHR_maintenance6 1
#define VK_KHR_MAINTENANCE_6_SPEC_VERSION 1
#define VK_KHR_MAINTENANCE_6_EXTENSION_NAME "VK_KHR_maintenance6"

#define VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_MAINTENANCE_6_FEATURES_KHR ((VkStructureType)1000545000)
#define VK_STRUCTURE_TYPE_BIND_DESCRIPTOR_SETS_INFO_KHR ((VkStructureType)1000545003)
#define VK_STRUCTURE_TYPE_PUSH_CONSTANTS_INFO_KHR ((VkStructureType)1000545004)
#define VK_STRUCTURE_TYPE_PUSH_DESCRIPTOR_SET_INFO_KHR ((VkStructureType)1000545005)
#define VK_STRUCTURE_TYPE_PUSH_DESCRIPTOR_SET_WITH_TEMPLATE_INFO_KHR ((VkStructureType)1000545006)

typedef struct VkPhysicalDeviceMaintenance6FeaturesKHR {
    VkStructureType sType;
    void*           pNext;
    VkBool32        maintenance6;
} VkPhysicalDeviceMaintenance6FeaturesKHR;

typedef struct VkBindDescriptorSetsInfoKHR {
    VkStructureType        sType;
    const void*            pNext;
    VkShaderStageFlags     stageFlags;
    VkPipelineLayout       layout;
    uint32_t               firstSet;
    uint32_t               descriptorSetCount;
    const VkDescriptorSet* pDescriptorSets;
    uint32_t               dynamicOffsetCount;
    const uint32_t*        pDynamicOffsets;
} VkBindDescriptorSetsInfoKHR;

typedef struct VkPushConstantsInfoKHR {
    VkStructureType    sType;
    const void*        pNext;
    VkPipelineLayout   layout;
    VkShaderStageFlags stageFlags;
    uint32_t           offset;
    uint32_t           size;
    const void*        pValues;
} VkPushConstantsInfoKHR;

typedef struct VkPushDescriptorSetInfoKHR {
    VkStructureType             sType;
    const void*                 pNext;
    VkShaderStageFlags          stageFlags;
    VkPipelineLayout            layout;
    uint32_t                    set;
    uint32_t                    descriptorWriteCount;
    const VkWriteDescriptorSet* pDescriptorWrites;
} VkPushDescriptorSetInfoKHR;

typedef struct VkPushDescriptorSetWithTemplateInfoKHR {
    VkStructureType            sType;
    const void*                pNext;
    VkDescriptorUpdateTemplate descriptorUpdateTemplate;
    VkPipelineLayout           layout;
    uint32_t                   set;
    const void*                pData;
} VkPushDescriptorSetWithTemplateInfoKHR;

typedef void(VKAPI_PTR* PFN_vkCmdBindDescriptorSets2KHR)(
    VkCommandBuffer commandBuffer, const VkBindDescriptorSetsInfoKHR* pBindDescriptorSetsInfo);
typedef void(VKAPI_PTR* PFN_vkCmdPushConstants2KHR)(
    VkCommandBuffer commandBuffer, const VkPushConstantsInfoKHR* pPushConstantsInfo);
typedef void(VKAPI_PTR* PFN_vkCmdPushDescriptorSet2KHR)(
    VkCommandBuffer commandBuffer, const VkPushDescriptorSetInfoKHR* pPushDescriptorSetInfo);
typedef void(VKAPI_PTR* PFN_vkCmdPushDescriptorSetWithTemplate2KHR)(
    VkCommandBuffer                               commandBuffer,
    const VkPushDescriptorSetWithTemplateInfoKHR* pPushDescriptorSetWithTemplateInfo);
#endif
