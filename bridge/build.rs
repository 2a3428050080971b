//! Tells the tests whether nxt-python, the independent NXT client the simulated brick is
//! tested against, can be imported (see `tes_probe`: its test runs when it can, and always
//! under CI).

fn main() {
    tes_probe::tell_tests(&[tes_probe::Client {
        cfg: "tes_nxt_python",
        imports: "import nxt.locator, nxt.motor",
    }]);
}
