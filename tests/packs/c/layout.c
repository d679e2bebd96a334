/* Prints the size of every ABI struct and the ABI constants, for comparison with the Rust side. */
#include <stdio.h>
#include "kairos.h"

int main(void) {
    printf("magic %llx\n", (unsigned long long)KAIROS_ABI_MAGIC);
    printf("abi %u\n", KAIROS_ABI_VERSION);
    printf("sdk %s\n", KAIROS_SDK_VERSION);
    printf("str %zu\n", sizeof(kairos_str));
    printf("sample %zu\n", sizeof(kairos_sample));
    printf("value %zu\n", sizeof(kairos_value));
    printf("error %zu\n", sizeof(kairos_error));
    printf("host %zu\n", sizeof(kairos_host));
    printf("counters %zu\n", sizeof(kairos_link_counters));
    printf("vtable %zu\n", sizeof(kairos_component_vtable));
    printf("descriptor %zu\n", sizeof(kairos_pack_descriptor));
    return 0;
}
