// Feeds sonar readings to MRPT's COccupancyGridMap2D, one CObservationRange per reading,
// and writes the resulting occupancy sampled at the centres of a given grid.
//
// usage: sonar_insert READINGS.bin N XMIN YMIN COLS ROWS RES CONE_DEG RMIN RMAX OUT.bin
//   READINGS.bin: N records of 4 float64 (x, y, theta, range), the sensor's world pose.
//   OUT.bin: ROWS x COLS float32, row 0 at the top (the map_server convention).
// Prints "insert_seconds S" (the insertion loop only) and "cells N" on stdout.
#include <mrpt/maps/COccupancyGridMap2D.h>
#include <mrpt/obs/CObservationRange.h>
#include <mrpt/poses/CPose3D.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <vector>

int main(int argc, char** argv)
{
	if (argc != 12)
	{
		std::cerr << "usage: sonar_insert READINGS.bin N XMIN YMIN COLS ROWS RES "
					 "CONE_DEG RMIN RMAX OUT.bin\n";
		return 2;
	}
	const long n = std::atol(argv[2]);
	const double xmin = std::atof(argv[3]), ymin = std::atof(argv[4]);
	const int cols = std::atoi(argv[5]), rows = std::atoi(argv[6]);
	const double res = std::atof(argv[7]);
	const double cone = std::atof(argv[8]) * M_PI / 180.0;
	const double rmin = std::atof(argv[9]), rmax = std::atof(argv[10]);

	std::vector<double> data(4 * n);
	{
		std::ifstream f(argv[1], std::ios::binary);
		f.read(reinterpret_cast<char*>(data.data()), 8 * 4 * n);
		if (f.gcount() != 8 * 4 * n)
		{
			std::cerr << argv[1] << ": expected " << n << " readings\n";
			return 2;
		}
	}

	// MRPT grows its grid when an echo falls within 15 cells of an edge; a margin of
	// 20 cells keeps it from resizing (and timing the copy) during the run.
	const double pad = 20 * res;
	mrpt::maps::COccupancyGridMap2D map(
		xmin - pad, xmin + cols * res + pad, ymin - pad, ymin + rows * res + pad, res);
	// Echoes up to r_max are valid; a reading at r_max has no echo.
	map.insertionOptions.maxDistanceInsertion = static_cast<float>(rmax);

	// One observation object, refilled per reading: its sensor sits at the robot
	// origin and the reading's world pose is passed as the robot pose.
	mrpt::obs::CObservationRange obs;
	obs.minSensorDistance = static_cast<float>(rmin);
	obs.maxSensorDistance = static_cast<float>(rmax);
	obs.sensorConeApperture = static_cast<float>(cone);
	obs.sensedData.resize(1);
	obs.sensedData[0].sensorID = 0;

	const auto t0 = std::chrono::steady_clock::now();
	for (long i = 0; i < n; i++)
	{
		const double* r = &data[4 * i];
		obs.sensedData[0].sensedDistance = static_cast<float>(r[3]);
		const mrpt::poses::CPose3D pose(r[0], r[1], 0.0, r[2], 0.0, 0.0);
		map.insertObservation(obs, pose);
	}
	const auto t1 = std::chrono::steady_clock::now();

	std::vector<float> out(static_cast<size_t>(rows) * cols);
	for (int i = 0; i < rows; i++)
		for (int j = 0; j < cols; j++)
		{
			const float x = static_cast<float>(xmin + (j + 0.5) * res);
			const float y = static_cast<float>(ymin + (rows - i - 0.5) * res);
			out[static_cast<size_t>(i) * cols + j] = map.getPos(x, y);
		}
	std::ofstream o(argv[11], std::ios::binary);
	o.write(reinterpret_cast<const char*>(out.data()), 4 * out.size());
	std::printf(
		"insert_seconds %.6f\ncells %zu\n",
		std::chrono::duration<double>(t1 - t0).count(), out.size());
	return 0;
}
