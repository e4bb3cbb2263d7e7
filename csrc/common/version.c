#include "fap_version.h"
#include "common/version_config.h"

const char *fap_version_string(void)
{
    return LF_VERSION;
}
