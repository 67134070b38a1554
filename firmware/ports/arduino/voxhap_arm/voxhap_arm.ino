// voxhap reference firmware on an Arduino-compatible board (Teensy 4.x, Arduino Due, any board with a fast USB
// serial port and micros()): the shape to copy for your own arm. Fill in the four functions marked BOARD.
//
// Setup: copy firmware/include/voxhap.h and firmware/src/voxhap_codec.c, voxhap_session.c, voxhap_fw.c into this
// sketch's folder (next to voxhap_arm.ino); the Arduino IDE or arduino-cli compiles them as C with the sketch.
// Then `voxhap serve --device serial:/dev/ttyACM0` (docs/firmware.md: bring-up checklist before the first contact).
//
// The example arm is Cartesian (three linear axes, one motor and one encoder each), so the kinematics are a scale
// per axis; for a linkage, replace them with your forward kinematics and Jacobian transpose.
#include "voxhap.h"

// ---------------------------------------------------------------------------------------------------- BOARD
static const int PWM_PIN[3] = {2, 3, 4};
static const int DIR_PIN[3] = {5, 6, 7};
static const int ESTOP_PIN = 8;              // emergency stop button to ground (INPUT_PULLUP): pressed = LOW
static const float M_PER_COUNT = 1.0e-5f;    // encoder resolution along each axis, metres per count
static const float N_PER_PWM = 5.0f / 255;   // force at full PWM (amplifier in current mode), newtons per step
static const float MAX_FORCE_N = 5.0f;       // what the arm can render safely; the firmware clamps to it

// BOARD: encoder counts of the three axes, signed, zero at the centre of the workspace (an index pulse or a
// homing move at power-up). Replace with your encoder interface (quadrature decoder peripheral, Encoder library).
static long read_encoder_counts(int axis) {
  (void)axis;
  return 0;
}

// BOARD: drive motor `axis` with a force in newtons along it (sign = direction).
static void drive_axis(int axis, float force_n) {
  float magnitude = force_n < 0 ? -force_n : force_n;
  int pwm = (int)(magnitude / N_PER_PWM + 0.5f);
  if (pwm > 255) pwm = 255;
  digitalWrite(DIR_PIN[axis], force_n < 0 ? LOW : HIGH);
  analogWrite(PWM_PIN[axis], pwm);
}

// ---------------------------------------------------------------------------------------------------- HAL
static uint32_t last_micros = 0, micros_high = 0;
static float last_position_m[3];
static uint64_t last_sample_us = 0;

// micros() wraps every 71 minutes: extend it to 64 bits (called at least every millisecond).
static uint64_t hal_now_us(void *) {
  uint32_t now = micros();
  if (now < last_micros) micros_high++;
  last_micros = now;
  return ((uint64_t)micros_high << 32) | now;
}

static size_t hal_uart_read(void *, uint8_t *buf, size_t cap) {
  size_t n = 0;
  while (n < cap && Serial.available() > 0) buf[n++] = (uint8_t)Serial.read();
  return n;
}

static void hal_uart_write(void *, const uint8_t *buf, size_t len) { Serial.write(buf, len); }

static void hal_read_sample(void *ctx, voxhap_sample *s) {
  uint64_t now = hal_now_us(ctx);
  float dt_s = (float)(uint32_t)(now - last_sample_us) * 1e-6f;
  for (int i = 0; i < 3; i++) {
    float x = (float)read_encoder_counts(i) * M_PER_COUNT;
    // A finite-difference velocity; filter it (or use a hardware timer capture) on a real arm.
    s->velocity_m_per_s[i] = dt_s > 0 ? (x - last_position_m[i]) / dt_s : 0.0f;
    s->position_m[i] = x;
    last_position_m[i] = x;
  }
  last_sample_us = now;
  s->buttons = 0;
}

static void hal_write_force(void *, const float force_n[3]) {
  for (int i = 0; i < 3; i++) drive_axis(i, force_n[i]);
}

static uint16_t hal_read_faults(void *) {
  return digitalRead(ESTOP_PIN) == LOW ? (1u << VOXHAP_FAULT_EMERGENCY_STOP) : 0;
}

// ---------------------------------------------------------------------------------------------------- sketch
static voxhap_fw fw;
static uint64_t last_control_us = 0;

void setup() {
  for (int i = 0; i < 3; i++) {
    pinMode(PWM_PIN[i], OUTPUT);
    pinMode(DIR_PIN[i], OUTPUT);
    analogWrite(PWM_PIN[i], 0);
  }
  pinMode(ESTOP_PIN, INPUT_PULLUP);
  Serial.begin(1000000);  // USB CDC ignores the rate; a raw UART needs >= 520 000 baud at 1 kHz

  voxhap_device_info info;
  memset(&info, 0, sizeof info);
  info.version.major = VOXHAP_VERSION_MAJOR;
  info.version.minor = VOXHAP_VERSION_MINOR;
  memcpy(info.model, "my-arm", 6);            // printable ASCII, at most 12 characters
  memcpy(info.serial_number, "0001", 4);
  info.position_dof = 3;
  info.force_dof = 3;
  info.button_count = 0;
  info.supported_rates = VOXHAP_RATE_500 | VOXHAP_RATE_1000;
  for (int i = 0; i < 3; i++) {
    info.workspace_min_m[i] = -0.1f;
    info.workspace_max_m[i] = 0.1f;
  }
  info.max_force_n = MAX_FORCE_N;
  info.max_stiffness_n_per_m = 1000.0f;     // the stiffest wall your arm renders stably at 1 kHz

  voxhap_hal hal;
  memset(&hal, 0, sizeof hal);
  hal.now_us = hal_now_us;
  hal.uart_read = hal_uart_read;
  hal.uart_write = hal_uart_write;
  hal.read_sample = hal_read_sample;
  hal.write_force = hal_write_force;
  hal.read_faults = hal_read_faults;
  // Force rise limited to 1 N per ms, twice the host's own limit: it only acts if something upstream misbehaves.
  if (voxhap_fw_init(&fw, &hal, &info, 1000.0f) != VOXHAP_OK) {
    for (;;) {  // an info that cannot be sent (a label with non-ASCII, a negative limit): fix it above
    }
  }
  voxhap_fw_start(&fw);  // zero force, then a lone 0x00 on the line
}

void loop() {
  // A control cycle after every message (the State goes out at once) and at least every millisecond (the watchdog).
  uint32_t handled = voxhap_fw_receive(&fw);
  uint64_t now = hal_now_us(nullptr);
  if (handled > 0 || now - last_control_us >= 1000) {
    last_control_us = now;
    voxhap_fw_control(&fw);
  }
}
