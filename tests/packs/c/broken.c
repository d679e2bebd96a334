/* A pack descriptor that is wrong in one way, chosen at compile time, to test the loader's checks. */
#include "kairos.h"

#ifndef PACK_MAGIC
#define PACK_MAGIC KAIROS_ABI_MAGIC
#endif
#ifndef PACK_ABI
#define PACK_ABI KAIROS_ABI_VERSION
#endif
#ifndef PACK_SAMPLE_SIZE
#define PACK_SAMPLE_SIZE sizeof(kairos_sample)
#endif

#define STR(text) { (const uint8_t *)(text), sizeof(text) - 1 }

static const kairos_pack_descriptor descriptor = {
    PACK_MAGIC, PACK_ABI, (uint32_t)sizeof(kairos_pack_descriptor), (uint32_t)(PACK_SAMPLE_SIZE),
    (uint32_t)sizeof(kairos_host), (uint32_t)sizeof(kairos_component_vtable), (uint32_t)sizeof(kairos_value),
    STR(KAIROS_SDK_VERSION), STR("broken"), STR("0.1.0"), 0, 0,
};

const kairos_pack_descriptor *kairos_pack_entry(void) { return &descriptor; }
