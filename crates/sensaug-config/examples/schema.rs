//! Prints the JSON Schema of a configuration file.
fn main() {
    println!(
        "{}",
        serde_json::to_string_pretty(sensaug_config::json_schema()).expect("a schema is JSON")
    );
}
