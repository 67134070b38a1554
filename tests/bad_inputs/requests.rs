//! The HTTP requests of the bad-inputs page (docs/bad-inputs.md): each is sent to a real server on
//! 127.0.0.1:0 by `bad_inputs`, which also generates the page's table from them.

/// One bad request to `voxhap serve` (listening on 127.0.0.1:PORT, control token TOKEN).
pub(super) struct RequestCase {
    pub(super) input: &'static str,
    /// The request; `{addr}` is replaced by the server's address.
    pub(super) request: &'static str,
    pub(super) status: u16,
    pub(super) expected: &'static str,
}

pub(super) const REQUESTS: &[RequestCase] = &[
    RequestCase {
        input: "a page reached through DNS rebinding (its own name, our address)",
        request: "GET /api/state HTTP/1.1\r\nHost: rebind.example:{port}\r\nConnection: close\r\n\r\n",
        status: 403,
        expected: "forbidden: Host \"rebind.example:{port}\" is not this server's address",
    },
    RequestCase {
        input: "a WebSocket opened by another site's page",
        request: "GET /ws HTTP/1.1\r\nHost: {addr}\r\nOrigin: https://evil.example\r\nConnection: Upgrade\r\nUpgrade: websocket\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\r\n",
        status: 403,
        expected: "forbidden: Origin \"https://evil.example\" is not this server's page",
    },
    RequestCase {
        input: "a control request sent by another site's page",
        request: "POST /api/stiffness HTTP/1.1\r\nHost: {addr}\r\nOrigin: https://evil.example\r\nContent-Length: 10\r\nConnection: close\r\n\r\n{\"k\": 450}",
        status: 403,
        expected: "forbidden: Origin \"https://evil.example\" is not this server's page",
    },
    RequestCase {
        input: "two Host headers, the server's own first",
        request: "GET /api/state HTTP/1.1\r\nHost: {addr}\r\nHost: rebind.example:{port}\r\nConnection: close\r\n\r\n",
        status: 400,
        expected: "bad request: 2 Host headers; a request carries at most one",
    },
    RequestCase {
        input: "two Origin headers, the page's own first",
        request: "POST /api/stiffness HTTP/1.1\r\nHost: {addr}\r\nOrigin: http://{addr}\r\nOrigin: https://evil.example\r\nContent-Length: 10\r\nConnection: close\r\n\r\n{\"k\": 450}",
        status: 400,
        expected: "bad request: 2 Origin headers; a request carries at most one",
    },
    RequestCase {
        input: "a coupling damping above the device's passivity bound",
        request: "POST /api/stiffness HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer TOKEN\r\nContent-Length: 16\r\nConnection: close\r\n\r\n{\"damping\": 1e6}",
        status: 400,
        // The built-in scene's k = 500 N/m on the simulated arm (b = 1 N s/m) at 1 kHz: 1 - 500 * 0.001 / 2.
        expected: "damping must be at most 0.75 N s/m",
    },
    RequestCase {
        input: "a friction mode with `mu = 1e300` added through the API",
        request: "POST /api/modes HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer TOKEN\r\nContent-Length: 65\r\nConnection: close\r\n\r\n{\"mode\": {\"kind\": \"friction\", \"surface\": \"surface\", \"mu\": 1e300}}",
        status: 400,
        expected: ".mu: must be a finite number from 0 to 10, got 1e300",
    },
    RequestCase {
        input: "a transfer function of `1e300` N set through the API",
        request: "POST /api/modes/surface/transfer HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer TOKEN\r\nContent-Length: 28\r\nConnection: close\r\n\r\n{\"transfer\": [[0.0, 1e300]]}",
        status: 400,
        expected: "strength must be from 0 to 1000000 N (breakpoint 0: 1e300)",
    },
    RequestCase {
        input: "a volume file outside the `--volume-dir` folders",
        request: "POST /api/volume HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer TOKEN\r\nContent-Length: 23\r\nConnection: close\r\n\r\n{\"path\": \"/etc/passwd\"}",
        status: 400,
        expected: "volume /etc/passwd: outside the --volume-dir folders",
    },
    RequestCase {
        input: "a recording started through the API without `--record-dir`",
        request: "POST /api/record/start HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer TOKEN\r\nContent-Length: 25\r\nConnection: close\r\n\r\n{\"path\": \"../escape.csv\"}",
        status: 400,
        expected: "recording to ../escape.csv: recording through the API is off; start voxhap serve with --record-dir DIR",
    },
    RequestCase {
        input: "a FIFO in the `--volume-dir` folder",
        request: "POST /api/volume HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer TOKEN\r\nContent-Length: 20\r\nConnection: close\r\n\r\n{\"path\": \"pipe.nii\"}",
        status: 400,
        expected: "it is a FIFO (named pipe), not a regular file",
    },
];
