pub mod reaction_wheel;
