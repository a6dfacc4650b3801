/* The machine's own limit for real-time delivery: a bare writer and a bare reader, no
 * emulator (tests/perf/bench_emulator.py compiles this with cc, as bench_model.py does
 * model_loop.c).
 *
 *   rt_pair MODE EPOCHS BYTES PERIOD_US PRIORITY
 *
 * MODE is pty (writer on the master, reader on the slave in raw mode), pipe, or tcp
 * (loopback 127.0.0.1, TCP_NODELAY). The writer (main thread) sleeps to 1 ms before each
 * absolute deadline start + k * PERIOD_US on CLOCK_MONOTONIC, spins to it, then writes
 * BYTES bytes: the emulator's own timing (emulator/output/scheduler.py). The reader
 * (a second thread) blocks in read() and timestamps each chunk as it returns; epoch k
 * arrives with the chunk holding its first byte. Both threads run SCHED_FIFO at
 * PRIORITY when PRIORITY > 0 and it is permitted (else as they are), memory locked
 * where permitted. Prints "rt_pair: fifo=0|1" on stderr, then one line per epoch on
 * stdout: k write_start_s write_end_s arrival_s writer_cpu.
 *
 *   rt_pair read SOURCE MARKER EPOCHS PRIORITY
 *
 * The bare reader alone, of another writer (the emulator): SOURCE is a pty's path (set
 * to raw mode), tcp:HOST:PORT (a loopback client, TCP_NODELAY) or - (standard input, a
 * pipe). It blocks in read(), timestamps each chunk as it returns, and an epoch arrives
 * with the chunk that completes its MARKER (the first sentence's ",4,1,"). SCHED_FIFO and
 * locked memory as above. Prints "rt_pair: fifo=0|1" on stderr, then "k arrival_s" per
 * epoch on stdout; stops after EPOCHS markers or at end of input.
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <pthread.h>
#include <pty.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

static int epochs, nbytes, prio;
static double *arrival;
static int rfd;

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static int fifo(void) {
    struct sched_param sp = {.sched_priority = prio};
    return prio > 0 && pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp) == 0;
}

static void *reader(void *arg) {
    (void)arg;
    fifo();
    static char buf[65536];
    long total = 0, want = (long)epochs * nbytes;
    while (total < want) {
        ssize_t n = read(rfd, buf, sizeof buf);
        if (n <= 0) {
            if (n < 0 && errno == EINTR) continue;
            break;
        }
        double t = now();
        for (long b = total; b < total + n; b++)
            if (b % nbytes == 0) arrival[b / nbytes] = t;
        total += n;
    }
    return NULL;
}

static void die(const char *what) {
    perror(what);
    exit(1);
}

static int read_only(const char *src, const char *marker, int count) {
    int fd;
    if (!strcmp(src, "-")) {
        fd = 0;
    } else if (!strncmp(src, "tcp:", 4)) {
        char host[256];
        const char *colon = strrchr(src + 4, ':');
        if (colon == NULL || colon - (src + 4) >= (long)sizeof host) die("tcp:HOST:PORT");
        memcpy(host, src + 4, colon - (src + 4));
        host[colon - (src + 4)] = 0;
        struct sockaddr_in a = {.sin_family = AF_INET, .sin_port = htons(atoi(colon + 1))};
        int one = 1;
        if (inet_pton(AF_INET, host, &a.sin_addr) != 1) die("inet_pton");
        fd = socket(AF_INET, SOCK_STREAM, 0);
        if (connect(fd, (struct sockaddr *)&a, sizeof a) < 0) die("connect");
        setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    } else {
        struct termios tio;
        fd = open(src, O_RDWR | O_NOCTTY);
        if (fd < 0) die("open");
        tcgetattr(fd, &tio);
        cfmakeraw(&tio);
        tcsetattr(fd, TCSANOW, &tio);
    }
    mlockall(MCL_CURRENT | MCL_FUTURE);
    fprintf(stderr, "rt_pair: fifo=%d\n", fifo());
    double *at = calloc(count, sizeof *at);
    size_t mlen = strlen(marker), keep = 0;
    static char buf[65536 + 64];
    int seen = 0;
    while (seen < count) {
        ssize_t n = read(fd, buf + keep, 65536);
        if (n <= 0) {
            if (n < 0 && errno == EINTR) continue;
            break;
        }
        double t = now();
        size_t len = keep + (size_t)n;
        /* the kept tail (mlen - 1 bytes) cannot hold a whole marker: every match is new */
        for (size_t i = 0; i + mlen <= len && seen < count; i++)
            if (!memcmp(buf + i, marker, mlen)) at[seen++] = t;
        keep = len < mlen - 1 ? len : mlen - 1;
        memmove(buf, buf + len - keep, keep);
    }
    for (int k = 0; k < seen; k++) printf("%d %.9f\n", k, at[k]);
    return 0;
}

int main(int argc, char **argv) {
    if (argc == 6 && !strcmp(argv[1], "read")) {
        prio = atoi(argv[5]);
        return read_only(argv[2], argv[3], atoi(argv[4]));
    }
    if (argc != 6) {
        fprintf(stderr, "usage: rt_pair pty|pipe|tcp EPOCHS BYTES PERIOD_US PRIORITY\n"
                        "       rt_pair read PTY|tcp:HOST:PORT|- MARKER EPOCHS PRIORITY\n");
        return 2;
    }
    const char *mode = argv[1];
    epochs = atoi(argv[2]);
    nbytes = atoi(argv[3]);
    long period_ns = atol(argv[4]) * 1000L;
    prio = atoi(argv[5]);
    arrival = calloc(epochs, sizeof *arrival);
    double *w0 = calloc(epochs, sizeof *w0), *w1 = calloc(epochs, sizeof *w1);
    int *cpu = calloc(epochs, sizeof *cpu);
    char *data = malloc(nbytes);
    memset(data, 'x', nbytes);
    int wfd;
    if (!strcmp(mode, "pty")) {
        int m, s;
        struct termios tio;
        if (openpty(&m, &s, NULL, NULL, NULL) < 0) die("openpty");
        tcgetattr(s, &tio);
        cfmakeraw(&tio);
        tcsetattr(s, TCSANOW, &tio);
        wfd = m;
        rfd = s;
    } else if (!strcmp(mode, "pipe")) {
        int p[2];
        if (pipe(p) < 0) die("pipe");
        rfd = p[0];
        wfd = p[1];
    } else if (!strcmp(mode, "tcp")) {
        int l = socket(AF_INET, SOCK_STREAM, 0), one = 1;
        struct sockaddr_in a = {.sin_family = AF_INET, .sin_port = 0};
        socklen_t len = sizeof a;
        a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        if (bind(l, (struct sockaddr *)&a, sizeof a) < 0 || listen(l, 1) < 0) die("listen");
        getsockname(l, (struct sockaddr *)&a, &len);
        rfd = socket(AF_INET, SOCK_STREAM, 0);
        if (connect(rfd, (struct sockaddr *)&a, sizeof a) < 0) die("connect");
        wfd = accept(l, NULL, NULL);
        if (wfd < 0) die("accept");
        setsockopt(wfd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        close(l);
    } else {
        fprintf(stderr, "rt_pair: unknown mode %s\n", mode);
        return 2;
    }
    mlockall(MCL_CURRENT | MCL_FUTURE);  /* where permitted; refused is fine */
    int rt = fifo();
    fprintf(stderr, "rt_pair: fifo=%d\n", rt);
    pthread_t th;
    if (pthread_create(&th, NULL, reader, NULL)) die("pthread_create");
    struct timespec start;
    clock_gettime(CLOCK_MONOTONIC, &start);
    start.tv_sec += 1;  /* let the reader block in read() first */
    for (int k = 0; k < epochs; k++) {
        long long ns = (long long)start.tv_sec * 1000000000LL + start.tv_nsec + (long long)k * period_ns;
        long long early = ns - 1000000LL;
        struct timespec ts = {.tv_sec = early / 1000000000LL, .tv_nsec = early % 1000000000LL};
        while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR) {
        }
        double deadline = ns * 1e-9;
        while (now() < deadline) {
        }
        w0[k] = now();
        if (write(wfd, data, nbytes) != nbytes) die("write");
        w1[k] = now();
        cpu[k] = sched_getcpu();
    }
    pthread_join(th, NULL);
    for (int k = 0; k < epochs; k++) printf("%d %.9f %.9f %.9f %d\n", k, w0[k], w1[k], arrival[k], cpu[k]);
    return 0;
}
