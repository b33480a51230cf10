//! The valve paper's Table 2 and Table 3 campaigns, printed beside the paper's numbers.
//! `cargo run --release -p prognos-sim --example valve_tables -- table2 [runs] [seed]`
//! `cargo run --release -p prognos-sim --example valve_tables -- table3 [seed]`

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let which = args.first().map(String::as_str).unwrap_or("table2");
    let num = |i: usize, default: u64| -> u64 {
        args.get(i)
            .map_or(default, |a| a.parse().expect("integer argument"))
    };
    match which {
        "table2" => {
            let result = prognos_sim::valve::table2(num(1, 5) as usize, num(2, 1));
            print!("{}", result.render());
        }
        "table3" => {
            let result = prognos_sim::valve::table3(num(1, 1));
            print!("{}", result.render());
        }
        other => {
            eprintln!("unknown table `{other}` (table2 or table3)");
            std::process::exit(2);
        }
    }
}
