/*
 * A select() loop Modbus TCP server on libmodbus (Debian's libmodbus-dev
 * 3.1.6): the C reference peer of scripts/bench-net.
 *
 * It holds the same spaces as the product's map, 266 coils (0-265) and 436
 * holding registers (0-435), all plain memory, so the requests the load
 * generator sends succeed on it too. One thread, one select() over the
 * listening socket and every client: the shape of libmodbus's own
 * tests/bandwidth-server-many-up.c, and of most small C servers.
 *
 *   libmodbus_server IP PORT      prints "listening on IP:PORT" once ready
 *
 * Built by scripts/bench-net:  gcc -O2 -o libmodbus_server libmodbus_server.c $(pkg-config --cflags --libs libmodbus)
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sys/select.h>
#include <sys/socket.h>

#include <modbus.h>

#define COILS 266
#define HOLDING_REGISTERS 436
#define BACKLOG 32

int main(int argc, char **argv)
{
    if (argc != 3) {
        fprintf(stderr, "usage: %s IP PORT\n", argv[0]);
        return 2;
    }
    modbus_t *ctx = modbus_new_tcp(argv[1], atoi(argv[2]));
    modbus_mapping_t *map = modbus_mapping_new(COILS, 0, HOLDING_REGISTERS, 0);
    if (ctx == NULL || map == NULL) {
        fprintf(stderr, "libmodbus_server: %s\n", modbus_strerror(errno));
        return 1;
    }
    int server = modbus_tcp_listen(ctx, BACKLOG);
    if (server == -1) {
        fprintf(stderr, "libmodbus_server: cannot listen on %s:%s: %s\n", argv[1], argv[2], modbus_strerror(errno));
        return 1;
    }
    printf("listening on %s:%s\n", argv[1], argv[2]);
    fflush(stdout);

    uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
    fd_set all;
    FD_ZERO(&all);
    FD_SET(server, &all);
    int max_fd = server;
    for (;;) {
        fd_set ready = all;
        if (select(max_fd + 1, &ready, NULL, NULL, NULL) == -1) {
            if (errno == EINTR)
                continue;
            perror("libmodbus_server: select");
            return 1;
        }
        for (int fd = 0; fd <= max_fd; fd++) {
            if (!FD_ISSET(fd, &ready))
                continue;
            if (fd == server) {
                int client = accept(server, NULL, NULL);
                if (client == -1) {
                    perror("libmodbus_server: accept");
                    continue;
                }
                if (client >= FD_SETSIZE) {
                    close(client);
                    continue;
                }
                int one = 1;
                setsockopt(client, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
                FD_SET(client, &all);
                if (client > max_fd)
                    max_fd = client;
                continue;
            }
            modbus_set_socket(ctx, fd);
            int rc = modbus_receive(ctx, query);
            if (rc > 0) {
                modbus_reply(ctx, query, rc, map);
            } else if (rc == -1) {
                /* The client closed the connection, or the stream is lost. */
                close(fd);
                FD_CLR(fd, &all);
                while (max_fd > server && !FD_ISSET(max_fd, &all))
                    max_fd--;
            }
        }
    }
}
