/* fapd_client.c - a client of `fap serve` in plain C: no libfap, only POSIX sockets.
 *
 * Speaks the daemon's client protocol (docs/daemon.md): each message is a 4-byte
 * big-endian length and that many bytes of UTF-8 JSON. It says hello (version 1.0),
 * sends one exec async transaction and prints the reply:
 *
 *   fap serve --protocol exec --port /dev/ttyUSB0 --listen unix:/run/fap/bus0.sock &
 *   ./fapd_client fapd:///run/fap/bus0.sock 5 0102        # node 5, payload 01 02
 *   ./fapd_client fapd://127.0.0.1:7000 5 0102
 *
 * Exit: 0 reply printed, 1 the transaction failed on the bus (no reply ...),
 * 3 no daemon / refused (as `fap` itself). The token, if the daemon wants one,
 * comes from $FAP_SERVE_TOKEN. The JSON reading here is a small scanner for the
 * daemon's compact objects (string fields it looks up by name), enough for the
 * fields this example needs; a real client would use a JSON library.
 */
#define _POSIX_C_SOURCE 200809L
#include <arpa/inet.h>
#include <errno.h>
#include <netdb.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#define MAX_MESSAGE (64 * 1024)

static int connect_url(const char *url)
{
    if (strncmp(url, "fapd://", 7) != 0)
        return -1;
    const char *rest = url + 7;
    if (rest[0] == '/') {                       /* fapd:///path: a Unix socket */
        struct sockaddr_un sa = {.sun_family = AF_UNIX};
        size_t n = strcspn(rest, "?");
        if (n >= sizeof sa.sun_path)
            return -1;
        memcpy(sa.sun_path, rest, n);
        int fd = socket(AF_UNIX, SOCK_STREAM, 0);
        if (fd >= 0 && connect(fd, (struct sockaddr *)&sa, sizeof sa) == 0)
            return fd;
        if (fd >= 0)
            close(fd);
        return -1;
    }
    char host[256];                             /* fapd://host:port */
    size_t n = strcspn(rest, "?/");
    if (n >= sizeof host)
        return -1;
    memcpy(host, rest, n);
    host[n] = '\0';
    char *colon = strrchr(host, ':');
    if (!colon)
        return -1;
    *colon = '\0';
    struct addrinfo hints = {.ai_socktype = SOCK_STREAM}, *res, *ai;
    if (getaddrinfo(host, colon + 1, &hints, &res) != 0)
        return -1;
    int fd = -1;
    for (ai = res; ai; ai = ai->ai_next) {
        fd = socket(ai->ai_family, ai->ai_socktype, ai->ai_protocol);
        if (fd >= 0 && connect(fd, ai->ai_addr, ai->ai_addrlen) == 0)
            break;
        if (fd >= 0)
            close(fd);
        fd = -1;
    }
    freeaddrinfo(res);
    return fd;
}

static int write_all(int fd, const void *buf, size_t n)
{
    const char *p = buf;
    while (n) {
        ssize_t w = write(fd, p, n);
        if (w < 0 && errno == EINTR)
            continue;
        if (w <= 0)
            return -1;
        p += w;
        n -= (size_t)w;
    }
    return 0;
}

static int read_all(int fd, void *buf, size_t n)
{
    char *p = buf;
    while (n) {
        ssize_t r = read(fd, p, n);
        if (r < 0 && errno == EINTR)
            continue;
        if (r <= 0)
            return -1;
        p += r;
        n -= (size_t)r;
    }
    return 0;
}

static int send_msg(int fd, const char *json)
{
    size_t n = strlen(json);
    unsigned char head[4] = {(unsigned char)(n >> 24), (unsigned char)(n >> 16),
                             (unsigned char)(n >> 8), (unsigned char)n};
    return write_all(fd, head, 4) || write_all(fd, json, n) ? -1 : 0;
}

/* The next message into buf (NUL-terminated); its length, or -1. */
static long recv_msg(int fd, char *buf, size_t cap)
{
    unsigned char head[4];
    if (read_all(fd, head, 4))
        return -1;
    uint32_t n = (uint32_t)head[0] << 24 | (uint32_t)head[1] << 16 | (uint32_t)head[2] << 8 | head[3];
    if (n == 0 || n > MAX_MESSAGE || n >= cap)
        return -1;
    if (read_all(fd, buf, n))
        return -1;
    buf[n] = '\0';
    return (long)n;
}

/* The string value of "key" in a compact JSON object, copied to out (no escapes
 * decoded: the fields read here are hex, names and plain messages). */
static int json_string(const char *obj, const char *key, char *out, size_t cap)
{
    char pat[64];
    snprintf(pat, sizeof pat, "\"%s\":\"", key);
    const char *p = strstr(obj, pat);
    if (!p)
        return -1;
    p += strlen(pat);
    size_t i = 0;
    while (*p && *p != '"' && i + 1 < cap) {
        if (*p == '\\' && p[1])
            p++;
        out[i++] = *p++;
    }
    out[i] = '\0';
    return 0;
}

int main(int argc, char **argv)
{
    if (argc != 4) {
        fprintf(stderr, "usage: %s fapd://URL NODE HEXDATA\n", argv[0]);
        return 2;
    }
    int fd = connect_url(argv[1]);
    if (fd < 0) {
        fprintf(stderr, "fapd_client: no daemon at %s\n", argv[1]);
        return 3;
    }
    static char buf[MAX_MESSAGE + 1];
    const char *token = getenv("FAP_SERVE_TOKEN");
    char hello[512];
    snprintf(hello, sizeof hello, "{\"op\":\"hello\",\"version\":[1,0],\"name\":\"fapd_client.c\""
             "%s%s%s}", token ? ",\"token\":\"" : "", token ? token : "", token ? "\"" : "");
    if (send_msg(fd, hello) || recv_msg(fd, buf, sizeof buf) < 0) {
        fprintf(stderr, "fapd_client: %s: the daemon closed the connection\n", argv[1]);
        return 3;
    }
    char text[512];
    if (strstr(buf, "\"op\":\"welcome\"") == NULL) {
        if (json_string(buf, "message", text, sizeof text))
            strcpy(text, "no welcome");
        fprintf(stderr, "fapd_client: refused: %s\n", text);
        return 3;
    }
    char req[1024];
    snprintf(req, sizeof req, "{\"op\":\"transact\",\"id\":1,\"node\":%d,\"data\":\"%.600s\"}",
             atoi(argv[2]), argv[3]);
    if (send_msg(fd, req) || recv_msg(fd, buf, sizeof buf) < 0) {
        fprintf(stderr, "fapd_client: the daemon closed the connection\n");
        return 3;
    }
    close(fd);
    if (strstr(buf, "\"ok\":true")) {
        if (json_string(buf, "data", text, sizeof text))
            text[0] = '\0';
        printf("node %s: %s\n", argv[2], text);
        return 0;
    }
    char type[64];
    if (json_string(buf, "type", type, sizeof type))
        strcpy(type, "error");
    if (json_string(buf, "message", text, sizeof text))
        text[0] = '\0';
    printf("node %s: %s: %s\n", argv[2], type, text);
    return 1;
}
