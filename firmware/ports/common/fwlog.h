/* A line-oriented event log of what a firmware received and did, written without printf (so a bare-metal port
 * needs no float formatting): every float is its IEEE-754 bit pattern in hex. firmware/tools/check_log.py reads it
 * and checks the firmware's safety rules and the host's promises (protocol/SPEC.md sections 6 and 7.1).
 *
 *   S <t_us> <seq> <fx> <fy> <fz> <flags>      SetForce received (force as f32 bits)
 *   M <t_us> <type> <arg>                      any other host message (type in hex; arg: version, timeout, ...)
 *   T <t_us> <type> <a> <b>                    a reply other than State sent (Fault: code, active faults;
 *                                              Rejected: type, reason; HeartbeatReply: status; DeviceInfo)
 *   A <t_us> <fx> <fy> <fz>                    force written to the motors, once per control cycle
 *   X <t_us> <event> <arg>                     port events: reset (firmware restarted), garbage bytes injected
 */
#ifndef FWLOG_H
#define FWLOG_H

#include "voxhap.h"

typedef struct {
    void (*write)(void *ctx, const char *text, uint32_t len);
    void *ctx;
    char line[128];
    uint32_t len;
} fwlog;

void fwlog_message(fwlog *log, const voxhap_host_msg *msg, uint64_t now_us);
void fwlog_reply(fwlog *log, const voxhap_device_msg *msg, uint64_t now_us);
void fwlog_applied(fwlog *log, const float force_n[3], uint64_t now_us);
void fwlog_event(fwlog *log, char kind, const char *event, uint32_t arg, uint64_t now_us);

#endif
