/*
 * sketch_sim.cpp - runs a reference sketch on the host against the stub Arduino API.
 *
 * Build (tests/test_firmware.py does it): g++ -DSKETCH='"../qube_bridge/qube_bridge.ino"'
 *   -I firmware/test/arduino_stub -I firmware/common sketch_sim.cpp fg_*.o
 *
 * Reads one request per line on stdin, answers with lines and a final ".":
 *   setup                 -> call setup()
 *   time US               -> set the clock (micros() wraps at 2^32 as on a real board)
 *   rx PORT HEX           -> bytes arrive on Serial (PORT 0) or Serial1 (PORT 1)
 *   miso HEX              -> what the SPI device answers in each transaction (17 bytes)
 *   run US                -> advance the clock in 50 us steps, calling loop() at each
 * After each request it prints what the sketch did: "spi MOSI_HEX CLOCK MODE SS" per SPI
 * transaction (SS: level of pin 10 during the transfers) and "tx0 HEX" / "tx1 HEX" for the
 * bytes written to Serial / Serial1.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "Arduino.h"
#include "SPI.h"

/* ---- the stub API ------------------------------------------------------------------------- */

static uint64_t sim_now = 1000;
static uint8_t sim_pins[64];
static uint8_t sim_miso[32];
static size_t sim_miso_len;
static char sim_spi_log[64][128];
static size_t sim_spi_count;
static uint8_t sim_mosi[32];
static size_t sim_mosi_len;
static SPISettings sim_settings(0, 0, 0);
static int sim_ss_during = -1;

HardwareSerial Serial;
HardwareSerial Serial1;
SPIClass SPI;

unsigned long micros(void) { return (unsigned long)(uint32_t)sim_now; }
void pinMode(uint8_t, uint8_t) {}
void digitalWrite(uint8_t pin, uint8_t value) { sim_pins[pin & 63] = value; }

void HardwareSerial::begin(unsigned long rate) { baud = rate; }
int HardwareSerial::available() { return (int)(rx_tail - rx_head); }
int HardwareSerial::read() { return rx_head < rx_tail ? rx[rx_head++] : -1; }
size_t HardwareSerial::write(uint8_t byte) { return write(&byte, 1); }
size_t HardwareSerial::write(const uint8_t *data, size_t len)
{
    if (tx_len + len > sizeof tx) len = sizeof tx - tx_len;
    memcpy(tx + tx_len, data, len);
    tx_len += len;
    return len;
}

void SPIClass::begin() {}
void SPIClass::beginTransaction(SPISettings settings)
{
    sim_settings = settings;
    sim_mosi_len = 0;
    sim_ss_during = -1;
}
uint8_t SPIClass::transfer(uint8_t byte)
{
    if (sim_ss_during == -1 || sim_pins[10] != 0) sim_ss_during = sim_pins[10];
    uint8_t answer = sim_mosi_len < sim_miso_len ? sim_miso[sim_mosi_len] : 0;
    if (sim_mosi_len < sizeof sim_mosi) sim_mosi[sim_mosi_len++] = byte;
    return answer;
}
void SPIClass::endTransaction()
{
    if (sim_spi_count >= 64) return;
    char *out = sim_spi_log[sim_spi_count++];
    for (size_t i = 0; i < sim_mosi_len; i++) sprintf(out + 2 * i, "%02x", sim_mosi[i]);
    sprintf(out + 2 * sim_mosi_len, " %lu %u %d", (unsigned long)sim_settings.clock,
            (unsigned)sim_settings.mode, sim_ss_during);
}

/* ---- the sketch --------------------------------------------------------------------------- */

#include SKETCH

/* ---- the driver --------------------------------------------------------------------------- */

static char sim_line[65536];

static size_t sim_hex(const char *tok, uint8_t *dst, size_t cap)
{
    size_t n = 0;
    while (tok && tok[0] && tok[1] && n < cap) {
        char pair[3] = {tok[0], tok[1], 0};
        dst[n++] = (uint8_t)strtoul(pair, NULL, 16);
        tok += 2;
    }
    return n;
}

static void sim_report(void)
{
    for (size_t i = 0; i < sim_spi_count; i++) printf("spi %s\n", sim_spi_log[i]);
    sim_spi_count = 0;
    HardwareSerial *ports[2] = {&Serial, &Serial1};
    for (int p = 0; p < 2; p++) {
        if (ports[p]->tx_len == 0) continue;
        printf("tx%d ", p);
        for (size_t i = 0; i < ports[p]->tx_len; i++) printf("%02x", ports[p]->tx[i]);
        printf("\n");
        ports[p]->tx_len = 0;
    }
}

int main(void)
{
    while (fgets(sim_line, sizeof sim_line, stdin) != NULL) {
        char *cmd = strtok(sim_line, " \t\r\n");
        if (cmd == NULL) {
        } else if (strcmp(cmd, "quit") == 0) {
            break;
        } else if (strcmp(cmd, "setup") == 0) {
            setup();
        } else if (strcmp(cmd, "time") == 0) {
            sim_now = strtoull(strtok(NULL, " \t\r\n"), NULL, 10);
        } else if (strcmp(cmd, "rx") == 0) {
            HardwareSerial *port = atoi(strtok(NULL, " \t\r\n")) ? &Serial1 : &Serial;
            if (port->rx_head == port->rx_tail) port->rx_head = port->rx_tail = 0;
            port->rx_tail += sim_hex(strtok(NULL, " \t\r\n"), port->rx + port->rx_tail,
                                     sizeof port->rx - port->rx_tail);
        } else if (strcmp(cmd, "miso") == 0) {
            sim_miso_len = sim_hex(strtok(NULL, " \t\r\n"), sim_miso, sizeof sim_miso);
        } else if (strcmp(cmd, "run") == 0) {
            uint64_t end = sim_now + strtoull(strtok(NULL, " \t\r\n"), NULL, 10);
            while (sim_now < end) {
                sim_now += 50;
                loop();
            }
        }
        sim_report();
        printf(".\n");
        fflush(stdout);
    }
    return 0;
}
