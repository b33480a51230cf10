pub mod edge_cloud;
