/* A pack that is wrong in one way, chosen at compile time, to test the loader's checks:
 *  PACK_MAGIC, PACK_ABI, PACK_SAMPLE_SIZE: a descriptor the layout and version checks refuse;
 *  PACK_NAME=...: the pack's name ("broken" by default);
 *  ABORT_IN_ENTRY: the entry point aborts the process;
 *  WITH_COMPONENT: one component, "broken.idle", that waits in core until stopped; with it,
 *    TYPE_NAME=... registers it under another name, and DEATH_FN, PROPERTY_FN, ACTION_FN=0 leave that
 *    function out of its table (a NULL pointer). */
#include <stdlib.h>

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
#ifndef PACK_NAME
#define PACK_NAME "broken"
#endif
#ifndef TYPE_NAME
#define TYPE_NAME "broken.idle"
#endif
#ifndef DEATH_FN
#define DEATH_FN lifecycle
#endif
#ifndef PROPERTY_FN
#define PROPERTY_FN named
#endif
#ifndef ACTION_FN
#define ACTION_FN named
#endif

#define STR(text) { (const uint8_t *)(text), sizeof(text) - 1 }

#ifdef WITH_COMPONENT
static int instance_storage;

static void *create(const void *data) {
    (void)data;
    return &instance_storage;
}

static void destroy(void *instance) { (void)instance; }

static int32_t lifecycle(void *instance, void *frame, const kairos_host *host, kairos_error *error) {
    (void)instance, (void)frame, (void)host, (void)error;
    return KAIROS_OK;
}

static int32_t core(void *instance, void *frame, const kairos_host *host, kairos_error *error) {
    (void)instance, (void)error;
    return host->wait(frame, 1);
}

static int32_t named(void *instance, void *frame, const kairos_host *host, kairos_str name, kairos_error *error) {
    (void)instance, (void)frame, (void)host, (void)name, (void)error;
    return KAIROS_OK;
}

static const kairos_component_vtable components[] = {{
    STR(TYPE_NAME),
    STR("{\"type_name\": \"" TYPE_NAME "\", \"pack\": \"" PACK_NAME "\", \"category\": \"test\", \"doc\": \"Waits\", "
        "\"mode\": \"threaded\", \"inputs\": [], \"outputs\": [], \"properties\": [], \"actions\": []}"),
    0, create, destroy, lifecycle, core, DEATH_FN, PROPERTY_FN, ACTION_FN,
}};
#define COMPONENTS components, 1
#else
#define COMPONENTS 0, 0
#endif

static const kairos_pack_descriptor descriptor = {
    PACK_MAGIC, PACK_ABI, (uint32_t)sizeof(kairos_pack_descriptor), (uint32_t)(PACK_SAMPLE_SIZE),
    (uint32_t)sizeof(kairos_host), (uint32_t)sizeof(kairos_component_vtable), (uint32_t)sizeof(kairos_value),
    STR(KAIROS_SDK_VERSION), STR(PACK_NAME), STR("0.1.0"), COMPONENTS,
};

const kairos_pack_descriptor *kairos_pack_entry(void) {
#ifdef ABORT_IN_ENTRY
    abort();
#endif
    return &descriptor;
}
