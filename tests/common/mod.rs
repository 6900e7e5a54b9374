pub mod mini_load;
