/* fap_version.h - libfap version, for programs that check at run time. */
#ifndef FAP_VERSION_H
#define FAP_VERSION_H
#ifdef __cplusplus
extern "C" {
#endif
/* "MAJOR.MINOR.PATCH" of the library actually loaded. */
const char *fap_version_string(void);
#ifdef __cplusplus
}
#endif
#endif
